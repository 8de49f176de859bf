"""Batched robot state as it comes out of the simulator backend.

All tensors are float32 torch tensors on the backend's device (``SimBackend.device``, ``sim/interface.py``)
with leading dimension B (number of robots); the env layer moves them to its device when the two differ.
Quaternions are MuJoCo's (w, x, y, z).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch


@dataclass
class RobotState:
    """One snapshot of B robots (views of the backend's shared buffers: copy to keep).

    Attributes:
        base_pos_w: (B, 3) [m] base (trunk frame origin) position, world frame.
        base_quat_w: (B, 4) base orientation quaternion (w, x, y, z), base -> world.
        base_lin_vel_w: (B, 3) [m/s] base origin linear velocity, world frame.
        base_ang_vel_b: (B, 3) [rad/s] base angular velocity, base frame.
        joint_pos: (B, 12) [rad] leg-major (FL, FR, RL, RR) x (hip, thigh, calf).
        joint_vel: (B, 12) [rad/s].
        joint_torque: (B, 12) [N m] torque applied during the last physics step (after clipping).
        foot_pos_w: (B, 4, 3) [m] foot sphere centres, world frame.
        foot_vel_w: (B, 4, 3) [m/s] foot sphere centre velocities, world frame.
        foot_force_w: (B, 4, 3) [N] contact force the ground exerts on each foot, world frame.
        phase: (B, 4) gait phase in [0, 1).
        contact_cmd: (B, 4) commanded stance flag from the gait generator (1.0 stance).
        base_contact: (B,) bool, True while the trunk, a hip or a thigh touches the ground
            (used by the termination manager; shanks and feet do not count).
        time: (B,) [s] simulated time since the robot's last reset.
        diverged: (B,) bool, True once the robot's simulation became invalid (NaN, MuJoCo
            error or warning); the robot is frozen until it is reset.
    """

    base_pos_w: torch.Tensor
    base_quat_w: torch.Tensor
    base_lin_vel_w: torch.Tensor
    base_ang_vel_b: torch.Tensor
    joint_pos: torch.Tensor
    joint_vel: torch.Tensor
    joint_torque: torch.Tensor
    foot_pos_w: torch.Tensor
    foot_vel_w: torch.Tensor
    foot_force_w: torch.Tensor
    phase: torch.Tensor
    contact_cmd: torch.Tensor
    base_contact: torch.Tensor
    time: torch.Tensor
    diverged: torch.Tensor

    def clone(self) -> RobotState:
        """Deep copy (the backend's tensors are live views that the next step overwrites)."""
        return RobotState(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def to(self, device: torch.device | str) -> RobotState:
        """The state on ``device`` (copies; the same tensors where already there)."""
        return RobotState(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def index(self, ids: torch.Tensor | slice) -> RobotState:
        """The state of a subset of robots."""
        return RobotState(**{f.name: getattr(self, f.name)[ids] for f in fields(self)})
