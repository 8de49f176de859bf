"""Frame helpers on (w, x, y, z) quaternions, batched over the leading dimension."""

from __future__ import annotations

import torch


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
