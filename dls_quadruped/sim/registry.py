"""The simulator backends by name: ``make_backend(scene.backend, model, num_envs, cfg)``.

The registry lives apart from the protocol it serves (``sim/interface.py``): the backends import the
protocol's module, and this one imports each backend only inside its factory, when it is built, so
MuJoCo Warp is loaded only for a Warp backend::

    sim = make_backend("cpu", model, num_envs=64, cfg=SimConfig(num_workers=0))

``cpu`` is :class:`dls_quadruped.sim.cpu_backend.VecSim` (MuJoCo's C batch + Pinocchio, worker processes);
``warp-cpu`` and ``cuda`` are :class:`dls_quadruped.sim.warp_backend.WarpSim` (MuJoCo Warp on Warp's CPU device or
on a CUDA GPU, the optional ``[gpu]`` extra, docs/gpu.md). A new backend registers a factory with
:func:`register_backend`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import mujoco

from dls_quadruped.core.registry import Registry
from dls_quadruped.sim.interface import SimBackend, SimConfig


class BackendUnavailableError(RuntimeError):
    """A registered backend that cannot run here: its optional packages or its device are missing."""


BackendFactory = Callable[[mujoco.MjModel, int, SimConfig], SimBackend]

BACKENDS: Registry[BackendFactory] = Registry("simulator backend")
"""The backend factories by name, each with a line for ``--help`` and error messages."""
DEFAULT_CONFIG = SimConfig()
"""What :func:`make_backend` builds with when given no ``SimConfig`` (frozen, shared safely)."""


def register_backend(name: str, factory: BackendFactory, description: str) -> None:
    """Make ``factory(model, num_envs, cfg)`` available as backend ``name`` (e.g. from a plugin module).

    Raises:
        ValueError: ``name`` is empty or already registered.
    """
    BACKENDS.register(name, factory, description)


def unregister_backend(name: str) -> None:
    """Remove backend ``name`` (tests that register a temporary one); unknown names are ignored."""
    BACKENDS.unregister(name)


def backend_names() -> tuple[str, ...]:
    """The registered backends, in registration order."""
    return BACKENDS.names()


def check_backend(name: Any) -> str:
    """``name`` if it is a registered backend, else a one-line ``ValueError`` naming the allowed ones."""
    return BACKENDS.check(name)


def make_backend(name: str, model: mujoco.MjModel, num_envs: int, cfg: SimConfig = DEFAULT_CONFIG) -> SimBackend:
    """Build backend ``name`` for ``num_envs`` robots of ``model``.

    Raises:
        ValueError: an unknown name (the message lists the registered ones).
        BackendUnavailableError: the backend's packages or device are missing (one line: what, and how to
            install it).
    """
    return BACKENDS.get(name)(model, num_envs, cfg)


def _cpu_backend(model: mujoco.MjModel, num_envs: int, cfg: SimConfig) -> SimBackend:
    if cfg.leg_dynamics == "pinocchio":
        try:
            import pinocchio  # noqa: F401  (the workers import it; fail here with one line instead)
        except ImportError:
            raise BackendUnavailableError(
                "simulator backend 'cpu' with leg_dynamics 'pinocchio' needs Pinocchio (pinocchio is not "
                "installed): pip install pin, or SimConfig(leg_dynamics='mujoco'), or a Warp backend") from None
    from dls_quadruped.sim.cpu_backend import VecSim

    return VecSim(model, num_envs, cfg)


register_backend("cpu", _cpu_backend, "MuJoCo C batch + Pinocchio on the CPU, one worker process per core")


def _warp_backend(device: str) -> BackendFactory:
    """Factory of the MuJoCo Warp backend on ``device``; imports MuJoCo Warp only when a backend is built."""

    def factory(model: mujoco.MjModel, num_envs: int, cfg: SimConfig) -> SimBackend:
        name = "warp-cpu" if device == "cpu" else device
        try:
            from dls_quadruped.sim.warp_backend import WarpSim
        except ImportError as err:
            if err.name not in ("warp", "mujoco_warp") and not (err.name or "").startswith(("warp.", "mujoco_warp.")):
                raise
            raise BackendUnavailableError(
                f"simulator backend {name!r} needs MuJoCo Warp ({err.name} is not installed): "
                "pip install -e .[gpu] (or make install-gpu); docs/gpu.md") from None
        try:
            return WarpSim(model, num_envs, cfg, device=device)
        except RuntimeError as err:
            if "needs a CUDA" in str(err):
                raise BackendUnavailableError(str(err)) from None
            raise

    return factory


register_backend("warp-cpu", _warp_backend("cpu"),
                 "MuJoCo Warp on Warp's CPU device, float32 (optional [gpu] extra; for checks, slow)")
register_backend("cuda", _warp_backend("cuda"), "MuJoCo Warp on a CUDA GPU, float32 (optional [gpu] extra)")
