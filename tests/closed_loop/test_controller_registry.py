"""The closed-loop controllers by name (``closed_loop/registry.py``): the six built in, in ``--controllers``
order, each its own class of the controller protocol (``envs/controller.py``), and a controller registered later
is validated and built by name like them."""

from __future__ import annotations

import pytest

from dls_quadruped.closed_loop.controllers import (
    CONTROLLERS,
    ControllerConfig,
    ExpertPolicy,
    MPCController,
    NaiveWarmStartMPC,
    PolicyController,
    RLWarmStartMPC,
    StudentPolicy,
    make_controller,
)
from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY
from dls_quadruped.closed_loop.split_warm_start import (
    NaiveGaitStudentForcesMPC,
    SplitWarmStartMPC,
    StudentGaitNaiveForcesMPC,
)
from dls_quadruped.envs.controller import EnvController


def test_the_six_controllers_in_order():
    assert CONTROLLERS == ("rl_warm_start", "naive_warm_start", "rl_baseline", "student", "rl_gait_naive_forces",
                           "naive_gait_rl_forces")
    assert CONTROLLERS == CONTROLLER_REGISTRY.names()
    classes = [CONTROLLER_REGISTRY.get(n) for n in CONTROLLERS]
    assert classes == [RLWarmStartMPC, NaiveWarmStartMPC, ExpertPolicy, StudentPolicy, StudentGaitNaiveForcesMPC,
                       NaiveGaitStudentForcesMPC]
    assert len(set(classes)) == 6  # one class per name: none branches on the name
    mpc, policies = classes[:2] + classes[4:], classes[2:4]
    assert all(issubclass(c, MPCController) for c in mpc)
    assert all(issubclass(c, SplitWarmStartMPC) for c in classes[4:])
    assert all(issubclass(c, PolicyController) and not issubclass(c, MPCController) for c in policies)
    assert all(issubclass(c, EnvController) for c in classes)
    assert all(CONTROLLER_REGISTRY.description(n) for n in CONTROLLERS)


def test_no_controller_reads_its_name_to_decide_what_to_do():
    """The controllers' modules never compare ``cfg.name`` (or ``self.name``) with a controller name."""
    import inspect

    from dls_quadruped.closed_loop import controller_base, controllers, mpc_controllers, split_warm_start

    for module in (controller_base, controllers, mpc_controllers, split_warm_start):
        source = inspect.getsource(module)
        for name in CONTROLLERS:
            for pattern in (f'name == "{name}"', f'name != "{name}"', f"name == '{name}'", f"name != '{name}'"):
                assert pattern not in source, (module.__name__, pattern)


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
