"""The closed-loop controllers by name (``closed_loop/registry.py``): the four built in, in ``--controllers``
order, and a controller registered later is validated and built by name like them."""

from __future__ import annotations

import pytest

from dls_quadruped.closed_loop.controllers import (
    CONTROLLERS,
    ControllerConfig,
    MPCController,
    PolicyController,
    make_controller,
)
from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY


def test_the_four_controllers_in_order():
    assert CONTROLLERS == ("rl_warm_start", "naive_warm_start", "rl_baseline", "student")
    assert CONTROLLERS == CONTROLLER_REGISTRY.names()
    assert [CONTROLLER_REGISTRY.get(n) for n in CONTROLLERS] == [MPCController, MPCController, PolicyController,
                                                                 PolicyController]
    assert all(CONTROLLER_REGISTRY.description(n) for n in CONTROLLERS)


def test_a_registered_controller_is_checked_and_built_by_name():
    built = []
    CONTROLLER_REGISTRY.register("scripted", lambda cfg, env: built.append((cfg.name, env)) or "controller",
                                 "a stand-in")
    try:
        assert make_controller(ControllerConfig("scripted"), "env") == "controller"
        assert built == [("scripted", "env")]
    finally:
        CONTROLLER_REGISTRY.unregister("scripted")
    with pytest.raises(ValueError, match=r"unknown controller 'scripted'; allowed: rl_warm_start \("):
        ControllerConfig("scripted")
