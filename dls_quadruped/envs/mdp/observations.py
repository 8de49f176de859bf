"""Observation terms (Table 2 + the velocity command). Each returns (num_envs, D), float32.

Noise is added by the observation manager (per-term uniform half-width in the task file).
"""

from __future__ import annotations

import torch

from dls_quadruped.core.rotations import quat_rotate_inverse
from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.height_scan import height_scan as _height_scan

CONTACT_FORCE_THRESHOLD = 1.0
"""[N] a foot is in contact when the normal (world z) ground force exceeds this."""


@constant_cache
def _gravity_dir_w(device: torch.device) -> torch.Tensor:
    """(3,) unit gravity direction (0, 0, -1), world frame (built once per device, read-only)."""
    return torch.tensor([0.0, 0.0, -1.0], device=device)


_NOMINAL_JOINT_POS = C.NOMINAL_JOINT_POS.tolist()  # Python numbers: no numpy value inside compiled code


@constant_cache
def _nominal_joint_pos(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(12,) [rad] ``constants.NOMINAL_JOINT_POS`` (built once per dtype and device, read-only)."""
    return torch.as_tensor(_NOMINAL_JOINT_POS, dtype=dtype, device=device)


def base_lin_vel(env) -> torch.Tensor:
    """(B, 3) [m/s] base linear velocity in the base frame."""
    s = env.state
    return quat_rotate_inverse(s.base_quat_w, s.base_lin_vel_w)


def base_ang_vel(env) -> torch.Tensor:
    """(B, 3) [rad/s] base angular velocity in the base frame."""
    return env.state.base_ang_vel_b


def projected_gravity(env) -> torch.Tensor:
    """(B, 3) unit gravity direction in the base frame ((0, 0, -1) when level)."""
    s = env.state
    g_w = _gravity_dir_w(s.base_quat_w.device).expand(s.base_quat_w.shape[0], 3)
    return quat_rotate_inverse(s.base_quat_w, g_w)


def joint_pos(env) -> torch.Tensor:
    """(B, 12) [rad] joint positions relative to the nominal standing pose."""
    q = env.state.joint_pos
    return q - _nominal_joint_pos(q.dtype, q.device)


def joint_vel(env) -> torch.Tensor:
    """(B, 12) [rad/s] joint velocities."""
    return env.state.joint_vel


def last_action(env) -> torch.Tensor:
    """(B, 28) last *applied* latent action in network units: raw minus its clipping violation."""
    return env.action_manager.applied_action


def leg_phase(env) -> torch.Tensor:
    """(B, 4) gait phase of each leg in [0, 1)."""
    return env.state.phase


def foot_contact(env, threshold: float = CONTACT_FORCE_THRESHOLD) -> torch.Tensor:
    """(B, 4) 1.0 where the ground pushes on the foot with more than ``threshold`` [N] (world z)."""
    return (env.state.foot_force_w[..., 2] > threshold).float()


def height_scan(env) -> torch.Tensor:
    """(B, 187) base z - terrain z - 0.5 m on the 17 x 11 yaw-aligned grid, clipped to +-1 m."""
    scene = env.scene
    s = env.state
    return _height_scan(scene.terrain, scene.scan_pattern, s.base_pos_w, s.base_quat_w, scene.scan_cfg)


def velocity_command(env) -> torch.Tensor:
    """(B, 3) commanded (v_x [m/s], v_y [m/s], omega_z [rad/s]) in the base/horizontal frame."""
    return env.command_manager.command
