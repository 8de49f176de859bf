"""The simulator seam: what every backend offers and its configuration.

Everything above ``sim/`` (the env's managers, the MDP terms, the closed loop, the eval suite) talks to the
simulator only through :class:`SimBackend`, so a second backend (MuJoCo Warp on a GPU, ``sim/warp_backend.py``) slots in
without touching them. The contract:

* **Inputs on any device, any float dtype.** ``set_references``, ``reset``, ``set_external_wrench``,
  ``set_base_velocity`` and ``set_model_field`` accept torch tensors (or numpy arrays) wherever they live;
  the backend moves them to where it computes. Rows are ``(n,)`` integer ids (tensors, lists or arrays) with
  ``n`` rows of values, or a ``(N,)`` bool tensor, a mask of the robots to change, with values for all ``N`` robots
  (the unmasked rows' values are ignored, and need not be finite): the env resets and pushes by masks, so that
  a GPU step has static shapes and reads nothing back (:func:`is_mask`).
* **State on the backend's device.** ``state`` (and what ``step`` / ``reset`` return) is a
  :class:`~dls_quadruped.core.state.RobotState` on :attr:`SimBackend.device`, live buffers that the next call
  overwrites (``RobotState.clone`` to keep one). The env copies it to its own device only when the two differ.
* **The host model is metadata.** ``model`` is the ``mujoco.MjModel`` the backend was built from (one MJCF, one
  terrain for every backend): names, ids, nominal values such as ``geom_friction``. Per-robot values are
  written with ``set_model_field``, never into ``model``.
* **Snapshots are opaque.** ``snapshot()`` returns what ``restore`` of a backend of the same kind and number of
  robots needs for a bit-identical next step (a checkpoint's episodes in progress).

Backends are built by name (``scene.backend`` in a task file) with ``make_backend`` of the registry,
``sim/registry.py``, which imports the backends and so lives apart from the protocol they implement::

    sim = make_backend("cpu", model, num_envs=64, cfg=SimConfig(num_workers=0))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, Self, runtime_checkable

import mujoco
import numpy as np
import torch

from dls_quadruped.control.lowlevel import LowLevelConfig
from dls_quadruped.core.state import RobotState
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.regions import RegionConfig


@dataclass(frozen=True)
class SimConfig:
    """Backend configuration (a backend ignores what does not apply to it).

    Attributes:
        num_workers: worker processes (``cpu``); 0 runs one shard in-process, -1 uses one per CPU core.
        nthread: threads of the in-process ``Batch`` when ``num_workers == 0`` (0: all cores).
        control: low-level controller gains.
    """

    num_workers: int = -1
    nthread: int = 0
    control: LowLevelConfig = field(default_factory=LowLevelConfig)
    reply_timeout_s: float = 120.0
    """Longest wait for a worker's answer before it is declared hung (a step takes milliseconds)."""
    start_timeout_s: float = 600.0
    """Longest wait for a worker to build its shard (imports and model loading on a busy machine)."""
    regions: RegionConfig | None = None
    """Per-robot terrain regions of a tiled terrain (``sim/regions.py``): each robot collides only with the
    geoms near it; None: every robot on the whole model (a plane, or tests that compare the two). The Warp
    backends cull the terrain per robot with it (``sim/warp_collision.py``: its ``margin``; cells of ``cell``,
    None there meaning 1 m, since a Warp cell is a row of geom ids, not a compiled model)."""
    nconmax: int | None = None
    """Warp backends: contacts allocated per robot (None: MuJoCo Warp's default for the model, 48 on a plane,
    128 with height fields). Lower it to fit more robots in GPU memory, raise it if the backend warns of an
    overflow (a robot whose world overflowed is flagged ``diverged``; docs/gpu.md "Contact and constraint sizes")."""
    njmax: int | None = None
    """Warp backends: constraint rows allocated per robot (None: MuJoCo Warp's default for the model; 4 rows per
    contact with pyramidal cones, plus joint limits)."""
    compile: bool | None = None
    """Warp backends: run the torch work of a physics step (controller, leg kinematics, divergence checks)
    compiled with ``torch.compile`` into a few fused kernels (``sim/warp_control.py``); None: on for CUDA devices,
    off elsewhere (compiling takes seconds and, on the CPU, a C++ compiler; a failure falls back to eager with a
    warning). The ``cpu`` backend ignores it."""
    leg_dynamics: str = "pinocchio"
    """``cpu``: where the low-level controller's leg terms (leg blocks of M, leg bias, foot Jacobians) come from
    at every physics step (:data:`LEG_DYNAMICS`): ``pinocchio`` (one Pinocchio call per robot, on the nominal
    robot model) or ``mujoco`` (MuJoCo's own mass matrix and bias forces of each robot's model, computed by a
    persistent ``Batch`` with the step, plus batched torch kinematics, ``control/torch_dynamics.py``). The two
    agree to round-off, but ``mujoco`` follows per-robot model values (``body_mass``, ...) that Pinocchio's
    nominal model ignores. Not faster on the 2-core development VM (0.82-1.04x, docs/benchmarks.md "Leg dynamics
    from MuJoCo"). The Warp backends always use MuJoCo's terms."""

    def __post_init__(self):
        check_leg_dynamics(self.leg_dynamics)


LEG_DYNAMICS: dict[str, str] = {
    "pinocchio": "Pinocchio on the nominal robot model, one call per robot (the default)",
    "mujoco": "MuJoCo's mass matrix and bias forces of each robot's model + batched torch kinematics",
}
"""Allowed values of :attr:`SimConfig.leg_dynamics`, with a line each."""


def check_leg_dynamics(name: Any) -> str:
    """``name`` if it is one of :data:`LEG_DYNAMICS`, else a one-line ``ValueError`` naming the allowed ones."""
    if not isinstance(name, str) or name not in LEG_DYNAMICS:
        allowed = ", ".join(f"{k} ({v})" for k, v in LEG_DYNAMICS.items())
        raise ValueError(f"unknown leg_dynamics {name!r}; allowed: {allowed}")
    return name


IdsLike = torch.Tensor | np.ndarray | list[int]
ArrayLike = torch.Tensor | np.ndarray


def robot_weight(model: mujoco.MjModel) -> float:
    """m g of the robot (the subtree of body 1, the trunk) in ``model`` [N]."""
    return float(model.body_subtreemass[1] * -model.opt.gravity[2])


def is_mask(rows: Any, num_envs: int) -> bool:
    """Whether ``rows`` (a backend method's ``env_ids``) is a (``num_envs``,) bool mask rather than row ids."""
    return isinstance(rows, torch.Tensor) and rows.dtype == torch.bool and tuple(rows.shape) == (num_envs,)


def standing_references(command: dict[str, torch.Tensor], rows: slice | torch.Tensor,
                        weight: float | torch.Tensor) -> None:
    """Write the standing references into ``command``'s ``rows`` (a slice, ids, or an (N,) bool mask): all four
    legs in stance (f = 0, d = 1),
    the weight shared equally, no foothold. Every backend gives these to a robot at construction and at
    its reset, until its first ``set_references`` (the state published at a reset reads the duty,
    ``contact_cmd = phase < d``, so a robot must not start an episode with its previous episode's duty). ``weight``
    [N]: a float, or a 0-d tensor on the command's device (what compiled code passes)."""
    for t, value in ((command["freq"], 0.0), (command["duty"], 1.0), (command["p_td_w"], 0.0), (command["F_w"], 0.0),
                     (command["F_w"][:, :, 2], weight / 4.0)):
        if isinstance(rows, torch.Tensor) and rows.dtype == torch.bool:
            t.masked_fill_(rows.to(t.device).view(-1, *[1] * (t.dim() - 1)), value)
        elif isinstance(rows, torch.Tensor):
            t.index_fill_(0, rows.to(t.device), value)  # t[rows] = value would copy value from the host on CUDA
        else:
            t[rows] = value


def reset_coordinates(rows: Callable[[str, Any, int, tuple[int, ...]], torch.Tensor], n: int, base_pos_w: Any,
                      base_quat_w: Any, joint_pos: Any, joint_vel: Any = None, base_lin_vel_w: Any = None,
                      base_ang_vel_b: Any = None, device: torch.device | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """``qpos`` (n, 19) and ``qvel`` (n, 18), float64, of ``SimBackend.reset``'s targets: the quaternion normalised,
    velocities not given zero. ``rows(name, value, n, shape)`` is the backend's check of one input (shape,
    finiteness) returning it as float64 (n, *shape) on ``device``."""
    zeros3 = torch.zeros(n, 3, dtype=torch.float64, device=device)
    quat = rows("base_quat_w", base_quat_w, n, (4,))
    qpos = torch.cat([rows("base_pos_w", base_pos_w, n, (3,)), quat / quat.norm(dim=1, keepdim=True),
                      rows("joint_pos", joint_pos, n, (12,))], dim=1)
    qvel = torch.cat(
        [zeros3 if base_lin_vel_w is None else rows("base_lin_vel_w", base_lin_vel_w, n, (3,)),
         zeros3 if base_ang_vel_b is None else rows("base_ang_vel_b", base_ang_vel_b, n, (3,)),
         torch.zeros(n, 12, dtype=torch.float64, device=device) if joint_vel is None
         else rows("joint_vel", joint_vel, n, (12,))], dim=1)
    return qpos, qvel


def home_state(num: int, seed: int, noise: float = 0.0, yaw: float | torch.Tensor = 0.0) -> dict[str, torch.Tensor]:
    """Home-keyframe reset targets, optionally with uniform joint noise [rad] (seeded) and base yaw [rad]."""
    gen = torch.Generator().manual_seed(seed)
    joint = torch.as_tensor(C.NOMINAL_JOINT_POS, dtype=torch.float64).expand(num, 12).clone()
    joint += noise * (2 * torch.rand(num, 12, generator=gen, dtype=torch.float64) - 1)
    pos = torch.tensor([0.0, 0.0, C.STANDING_BASE_HEIGHT + 0.005], dtype=torch.float64).expand(num, 3)
    half = torch.as_tensor(yaw, dtype=torch.float64).expand(num) / 2
    zero = torch.zeros(num, dtype=torch.float64)
    quat = torch.stack([torch.cos(half), zero, zero, torch.sin(half)], dim=1)
    return {"base_pos_w": pos, "base_quat_w": quat, "joint_pos": joint}


@runtime_checkable
class SimBackend(Protocol):
    """N AlienGo robots simulated and controlled by the low-level controller as one batch (see the module
    docstring for the device contract). Usable as a context manager (``close`` on exit)."""

    model: mujoco.MjModel
    """The host model the backend was built from: names, ids and nominal values (read-only metadata)."""
    num_envs: int
    physics_dt: float
    """[s] one physics (= low-level control) step."""
    device: torch.device
    """Where ``state`` lives."""
    state: RobotState
    """The latest state of every robot (live buffers)."""

    def total_weight(self) -> float:
        """m g of the robot [N]."""
        ...

    def set_references(self, freq: ArrayLike, duty: ArrayLike, p_td_w: ArrayLike, F_w: ArrayLike) -> None:
        """World-frame latent references of every robot, held until the next call: freq (N, 4) [Hz], duty (N, 4),
        p_td_w (N, 4, 3) [m] touch-down targets, F_w (N, 4, 3) [N] stance forces."""
        ...

    def step(self, num_physics_steps: int = 1) -> RobotState:
        """Advance every valid robot by ``num_physics_steps`` physics steps, low-level control at each."""
        ...

    def reset(self, env_ids: IdsLike, base_pos_w: ArrayLike, base_quat_w: ArrayLike, joint_pos: ArrayLike,
              joint_vel: ArrayLike | None = None, base_lin_vel_w: ArrayLike | None = None,
              base_ang_vel_b: ArrayLike | None = None, phase: ArrayLike | None = None) -> RobotState:
        """Reset robots ``env_ids`` to the given state (velocities default to zero, phases to trot); their
        wrench is cleared and they stand until their next references."""
        ...

    def set_external_wrench(self, env_ids: IdsLike, force_w: ArrayLike, torque_w: ArrayLike) -> None:
        """Constant external force [N] and torque [N m] on the base (world frame) until changed."""
        ...

    def set_base_velocity(self, env_ids: IdsLike, lin_vel_w: ArrayLike) -> RobotState:
        """Set the base linear velocity (world frame) of robots ``env_ids``: a push."""
        ...

    def set_model_field(self, name: str, env_ids: IdsLike, values: ArrayLike,
                        index: np.ndarray | list[int] | None = None) -> None:
        """Per-robot model values (``geom_friction``, ``body_mass``, ...), optionally only rows ``index`` of the
        field's first dimension."""
        ...

    def snapshot(self) -> dict:
        """The whole simulation state, for a checkpoint (opaque to the caller)."""
        ...

    def restore(self, snap: dict) -> RobotState:
        """Load :meth:`snapshot` output of a backend of the same kind and number of robots."""
        ...

    def close(self) -> None:
        """Free workers and device memory (idempotent)."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...
