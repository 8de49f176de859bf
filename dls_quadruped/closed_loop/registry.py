"""The closed-loop controllers by name: ``ControllerConfig.name`` -> ``factory(cfg, env) -> Controller``.

The registry lives apart from the protocol it serves (``closed_loop/controllers.py``, where the four controllers
of thesis 7.3.1 register themselves and ``make_controller`` builds one)::

    CONTROLLER_REGISTRY.get("naive_warm_start")(cfg, env)   # the model-based baseline acting in env
    CONTROLLER_REGISTRY.check("mpc")                       # ValueError: unknown controller 'mpc'; allowed: ...

A new controller registers a factory with ``CONTROLLER_REGISTRY.register(name, factory, description)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from dls_quadruped.core.registry import Registry

ControllerFactory = Callable[[Any, Any], Any]
"""(ControllerConfig, env) -> Controller."""

CONTROLLER_REGISTRY: Registry[ControllerFactory] = Registry("controller")
"""Every closed-loop controller by name, in the order ``--controllers`` lists them."""
