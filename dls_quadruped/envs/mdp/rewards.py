"""Reward terms of Table 4. Each returns the *unweighted* value (B,); the reward manager multiplies
by the weight and the policy step dt (IsaacLab convention)."""

from __future__ import annotations

import torch

from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.envs.mdp import kernels, mpc_cost
from dls_quadruped.envs.mdp.observations import (
    base_lin_vel,
    foot_contact,
    projected_gravity,
)
from dls_quadruped.robots.aliengo import constants as C

_COMPONENTS = {"f": slice(0, 4), "d": slice(4, 8), "p": slice(8, 16), "F": slice(16, 28)}


def track_lin_vel_xy(env, sigma: float = 0.5) -> torch.Tensor:
    """SEK on the base-frame planar velocity error v_xy - v_ref,xy [m/s]."""
    return kernels.sek(base_lin_vel(env)[:, :2] - env.command_manager.command[:, :2], sigma)


def track_lin_vel_xy_soft(env, sigma: float = 0.5, alpha_max: float = 0.5) -> torch.Tensor:
    """SSEK (Appendix D) on the planar velocity; slack alpha = alpha_max x terrain difficulty in [0, 1]."""
    alpha = alpha_max * env.scene.difficulty
    return kernels.ssek_velocity(base_lin_vel(env)[:, :2], env.command_manager.command[:, :2], sigma, alpha)


def track_ang_vel_z(env, sigma: float = 0.5) -> torch.Tensor:
    """SEK on the yaw-rate error omega_z - omega_ref [rad/s]."""
    return kernels.sek(env.state.base_ang_vel_b[:, 2] - env.command_manager.command[:, 2], sigma)


def lin_vel_z(env) -> torch.Tensor:
    """L2 of the base-frame vertical velocity [m^2/s^2]."""
    return kernels.l2(base_lin_vel(env)[:, 2])


def ang_vel_xy(env) -> torch.Tensor:
    """L2 of the roll and pitch rates [rad^2/s^2]."""
    return kernels.l2(env.state.base_ang_vel_b[:, :2])


def proprioceptive_height(env) -> torch.Tensor:
    """(B,) h = z_base - mean z of the feet in contact (eq. 4.3.6) [m], foot-sphere centres; NaN without contact."""
    c = foot_contact(env)
    z_feet = env.state.foot_pos_w[..., 2]
    n = c.sum(dim=-1)
    return env.state.base_pos_w[:, 2] - (c * z_feet).sum(dim=-1) / n  # 0/0 = NaN when airborne


def base_height(env, target: float = float(C.BASE_HEIGHT_TARGET - C.FOOT_RADIUS), sigma: float = 0.1,
                alpha: float = 0.0) -> torch.Tensor:
    """SEK (alpha = 0) or SSEK (alpha > 0, tolerance +-alpha [m]) on the proprioceptive height; 0 with no
    foot in contact (the height is undefined then). ``target`` defaults to the base height target
    (``constants.BASE_HEIGHT_TARGET``, shared with the MPC) above the foot-sphere centres."""
    h = proprioceptive_height(env)
    r = kernels.ssek_scalar(h - target, sigma, alpha)
    return torch.where(torch.isnan(h), torch.zeros_like(r), r)


def flat_orientation(env) -> torch.Tensor:
    """L2 of the projected gravity's x, y components (0 when the base is level)."""
    return kernels.l2(projected_gravity(env)[:, :2])


def cost_of_transport(env, alpha: float = 0.3, min_speed: float = 0.1) -> torch.Tensor:
    """L1 of the cost of transport (eq. 4.3.7) with the base's horizontal speed."""
    s = env.state
    speed = torch.linalg.vector_norm(s.base_lin_vel_w[:, :2], dim=-1)
    return kernels.l1(kernels.cost_of_transport(s.joint_torque, s.joint_vel, speed, env.robot_weight, alpha, min_speed))


def action_rate(env) -> torch.Tensor:
    """L2 of the change of the raw action between two policy steps."""
    am = env.action_manager
    return kernels.l2(am.raw_action - am.prev_raw_action)


_JOINT_RANGES = C.JOINT_RANGES.tolist()  # Python numbers: no numpy value inside compiled code


@constant_cache
def _joint_ranges(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(12, 2) [rad] ``constants.JOINT_RANGES`` (low, high) (built once per dtype and device, read-only)."""
    return torch.as_tensor(_JOINT_RANGES, dtype=dtype, device=device)


def joint_soft_limits(env, soft_ratio: float = 0.9) -> torch.Tensor:
    """L2 of how far joints are outside the central ``soft_ratio`` of their range [rad^2]."""
    q = env.state.joint_pos
    lim = _joint_ranges(q.dtype, q.device)
    mid, half = lim.mean(dim=1), 0.5 * (lim[:, 1] - lim[:, 0]) * soft_ratio
    return kernels.l2(torch.clamp((q - mid).abs() - half, min=0.0))


def clipping_violation(env, max_violation: float | None = None) -> torch.Tensor:
    """L2 of the clipping violation raw - normalise(clipped) (network units). ``max_violation``: each entry's
    magnitude counted up to this many units past the clip (None: unbounded, the thesis's term), so one robot whose
    action means run far out of range for an episode cannot put a return of -10^4 into a PPO batch (the climb runs'
    dips, docs/experts.md); exploration noise a few units past the clip is penalised as before."""
    v = env.action_manager.violation
    if max_violation is not None:
        if not max_violation > 0:
            raise ValueError(f"clipping_violation: max_violation must be > 0 (units past the clip) or null, "
                             f"got {max_violation!r}")
        v = v.clamp(-max_violation, max_violation)
    return kernels.l2(v)


def action_limit(env, component: str, low: float, high: float) -> torch.Tensor:
    """L1 of how far a latent component (``f`` [Hz], ``d``, ``p`` [m], ``F`` [N]) leaves [low, high],
    a range tighter than the clip (4.3.1 "action constraint"), summed over legs."""
    if component not in _COMPONENTS:
        raise ValueError(f"action_limit: unknown component {component!r}; allowed: {sorted(_COMPONENTS)}")
    x = env.action_manager.applied_physical[:, _COMPONENTS[component]]
    return kernels.l1(torch.clamp(low - x, min=0.0) + torch.clamp(x - high, min=0.0))


def mpc_trajectory_cost(env, reference_cost: float = 200.0, com_height: float = 0.404, clip: float = 50.0,
                        split_every: int = 10) -> torch.Tensor:
    """The sampling MPC's state cost of each robot's horizon action rolled out from its state, over
    ``reference_cost`` and clipped at ``clip`` (``mdp/mpc_cost.py``; needs ``actions.horizon``). ``com_height``
    [m]: the MPC's CoM height reference (0.404: the height the recipe experts walk at). Its split by cost term
    (computed every ``split_every``-th step) is logged as ``Episode_Reward/mpc_trajectory_cost/<term>``."""
    return mpc_cost.trajectory_cost(env, reference_cost, com_height, clip, split_every)


mpc_trajectory_cost.parts = mpc_cost.parts  # the reward manager logs the split by term
