"""Rotations on (w, x, y, z) quaternions (MuJoCo's order) and Z-Y-X Euler angles, batched.

A quaternion ``q`` maps body to world; ``R = Rz(yaw) Ry(pitch) Rx(roll)``. One place for every
layer (control, sim, envs, mpc, eval): these were scattered over four modules before.
"""

from __future__ import annotations

import torch


def quat_to_rotmat(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """Rotation matrix base -> world from (w, x, y, z) quaternions, (..., 4) -> (..., 3, 3)."""
    w, x, y, z = quat_wxyz.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*quat_wxyz.shape[:-1], 3, 3)


def rpy_from_rotmat(R: torch.Tensor) -> torch.Tensor:
    """(roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll); (..., 3, 3) -> (..., 3)."""
    roll = torch.atan2(R[..., 2, 1], R[..., 2, 2])
    pitch = torch.asin((-R[..., 2, 0]).clamp(-1.0, 1.0))
    yaw = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    return torch.stack([roll, pitch, yaw], dim=-1)


def euler_from_quat(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """(roll, pitch, yaw) of a body -> world quaternion (w, x, y, z), for R = Rz Ry Rx.

    Args:
        quat_wxyz: (..., 4), need not be normalised.

    Returns:
        (..., 3) [rad]; pitch in [-pi/2, pi/2].
    """
    q = quat_wxyz / torch.linalg.vector_norm(quat_wxyz, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    roll = torch.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))  # atan2(R32, R33)
    pitch = torch.asin((2 * (w * y - z * x)).clamp(-1.0, 1.0))  # asin(-R31)
    yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))  # atan2(R21, R11)
    return torch.stack([roll, pitch, yaw], dim=-1)


def yaw_from_quat(quat_w: torch.Tensor) -> torch.Tensor:
    """Yaw [rad] of (..., 4) quaternions (w, x, y, z), ZYX convention."""
    w, x, y, z = quat_w.unbind(-1)
    return torch.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_rotate_inverse(q_w: torch.Tensor, v_w: torch.Tensor) -> torch.Tensor:
    """Express world vectors in the body frame: R(q)^T v. q_w: (B, 4) body -> world; v_w: (B, 3)."""
    w, xyz = q_w[:, :1], q_w[:, 1:]
    t = 2.0 * torch.cross(xyz, v_w, dim=-1)
    return v_w - w * t + torch.cross(xyz, t, dim=-1)


def quat_rotate(q_w: torch.Tensor, v_b: torch.Tensor) -> torch.Tensor:
    """Express body vectors in the world frame: R(q) v. (B, 3)."""
    w, xyz = q_w[:, :1], q_w[:, 1:]
    t = 2.0 * torch.cross(xyz, v_b, dim=-1)
    return v_b + w * t + torch.cross(xyz, t, dim=-1)


def quat_from_yaw(yaw: torch.Tensor) -> torch.Tensor:
    """(B,) yaw [rad] -> (B, 4) quaternion (w, x, y, z) about world z."""
    half = 0.5 * yaw
    zeros = torch.zeros_like(yaw)
    return torch.stack([torch.cos(half), zeros, zeros, torch.sin(half)], dim=-1)
