"""The state and command buffers every simulator backend shares with its users, and what they are read from.

``STATE_SPECS`` is the layout of the published state (float32, one row per robot, named as ``RobotState``'s
fields) and ``COMMAND_SPECS`` that of the held commands (float64): the CPU backend keeps them in
:class:`SharedBuffers` (shared memory with its worker processes, ``sim/shard.py``), the Warp backends in device
tensors of the same names and shapes (``sim/warp_backend.py``). Both read the contact sensors through
:func:`contact_sensor_layout` and flag a robot whose velocities pass :data:`MAX_ABS_QVEL` as diverged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import torch

from dls_quadruped.robots.aliengo import constants as C

MAX_ABS_QVEL = 1.0e3
"""Generalized velocities beyond this [m/s, rad/s] mark a robot as diverged."""

STATE_SPECS: dict[str, tuple[int, ...]] = {
    "base_pos_w": (3,),
    "base_quat_w": (4,),
    "base_lin_vel_w": (3,),
    "base_ang_vel_b": (3,),
    "joint_pos": (12,),
    "joint_vel": (12,),
    "joint_torque": (12,),
    "foot_pos_w": (4, 3),
    "foot_vel_w": (4, 3),
    "foot_force_w": (4, 3),
    "phase": (4,),
    "contact_cmd": (4,),
    "base_contact": (),
    "time": (),
    "diverged": (),
}
"""Shapes (after the batch dim) of the float32 state buffers, named as RobotState fields."""

COMMAND_SPECS: dict[str, tuple[int, ...]] = {
    "freq": (4,),
    "duty": (4,),
    "p_td_w": (4, 3),
    "F_w": (4, 3),
    # reset targets, read for the ids of a reset command
    "reset_qpos": (19,),
    "reset_qvel": (18,),
    "reset_phase": (4,),
    # constant base wrench (world frame) and base-velocity overrides (pushes)
    "wrench_w": (6,),
    "set_lin_vel_w": (3,),
}
"""Shapes of the float64 command buffers written by the backend and read by shards."""

def contact_sensor_layout(model: mujoco.MjModel) -> dict[str, slice]:
    """Where each contact sensor of the AlienGo scene (four feet, trunk, four thighs) lies in ``sensordata``."""
    out = {}
    for name in (*(f"{leg}_foot_contact" for leg in C.LEG_NAMES), "trunk_contact",
                 *(f"{leg}_thigh_contact" for leg in C.LEG_NAMES)):
        s = model.sensor(name)
        out[name] = slice(int(s.adr[0]), int(s.adr[0] + s.dim[0]))
    return out


def _views(specs: dict[str, tuple[int, ...]], num_robots: int, dtype: torch.dtype,
           shared: bool) -> dict[str, torch.Tensor]:
    """Zeroed (num_robots, *shape) tensors, one per spec, carved in order out of one block."""
    sizes = {k: num_robots * math.prod(shape) for k, shape in specs.items()}
    block = torch.zeros(sum(sizes.values()), dtype=dtype)
    if shared:
        block.share_memory_()
    out, start = {}, 0
    for k, shape in specs.items():
        out[k] = block[start:start + sizes[k]].view(num_robots, *shape)
        start += sizes[k]
    return out


@dataclass
class SharedBuffers:
    """Named float tensors for all robots; shards use row slices of them."""

    state: dict[str, torch.Tensor]
    command: dict[str, torch.Tensor]

    @staticmethod
    def allocate(num_robots: int, shared: bool) -> SharedBuffers:
        """Zeroed buffers; ``shared=True`` puts them in shared memory for worker processes.

        The state buffers are views of one float32 block and the commands of one float64 block, so a shared set
        holds two shared-memory segments (two file descriptors under torch's default sharing strategy), not one
        per buffer; each buffer is contiguous, rows first."""
        return SharedBuffers(_views(STATE_SPECS, num_robots, torch.float32, shared),
                             _views(COMMAND_SPECS, num_robots, torch.float64, shared))

    def rows(self, start: int, stop: int) -> SharedBuffers:
        """Views of rows [start, stop)."""
        return SharedBuffers(
            {k: v[start:stop] for k, v in self.state.items()}, {k: v[start:stop] for k, v in self.command.items()}
        )
