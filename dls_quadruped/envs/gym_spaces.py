"""gymnasium spaces of a ``LocomotionEnv``: the latent action and the observation groups, with true bounds.

Action: the 28-vector in network units (Table 5, ``control/latent_action.py``) as a ``Box`` over
the *normalised range* -- the raw values that the Table 1 clip leaves unchanged for some stance
count. Entry by entry, ``(limit - shift) / scale``:

    f     [0, 3] Hz,             shift 1.5, scale 0.2    -> [-7.5, 7.5]
    d     [0, 1],                shift 0.6, scale 0.03   -> [-20, 13.33]
    p_x   [-0.10, 0.15] m,       shift 0,   scale 0.0175 -> [-5.71, 8.57]
    p_y   [-0.10, 0.10] m,       shift 0,   scale 0.0175 -> [-5.71, 5.71]
    F_x,y |F_xy| <= mu F_z <= mu m g, scale 0.025 m g   -> [-20, 20]   (mu = 0.5)
    F_z   [0, m g], shift m g / n (n = 1..4 legs in stance), scale 0.1 m g
                                 -> [(0 - m g) / 0.1 m g, (m g - m g / 4) / 0.1 m g] = [-10, 7.5]

The env accepts any finite action (outside the box it clips and the action-limit rewards penalise),
so the box says where an action has its full effect, not what is allowed.

Observations: a ``Dict`` of one ``Box`` per group, each the concatenation of its terms' bounds
(``TERM_BOUNDS``), widened by the term's uniform noise (``noise x noise_scale``) and by a few float32
ulps (the noise draw and the quaternion rotations round). A term without known bounds (velocities,
joint positions -- MuJoCo's joint limits are soft --, the command, which curricula widen) is
unbounded.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium
import numpy as np

from dls_quadruped.control.latent_action import ACTION_DIM, LatentActionConfig
from dls_quadruped.envs.mdp import observations as obs_mdp
from dls_quadruped.robots.aliengo import constants as C

FLOAT32_MARGIN = 4 * float(np.finfo(np.float32).eps)
"""Relative widening of finite observation bounds: float32 rounding of noise draws and rotations."""

Bounds = tuple[np.ndarray, np.ndarray]
"""(low, high), each (D,) float64."""


def action_bounds(cfg: LatentActionConfig) -> Bounds:
    """(28,) low and high of the normalised range (module docstring), in the action layout.

    Args:
        cfg: the task's latent-action constants (``env.action_manager.cfg``).
    """
    w = cfg.weight  # m g [N]
    p_scale = cfg.foothold_scale_frac * cfg.hip_height  # [m]
    fxy_scale, fz_scale = cfg.force_xy_scale_frac * w, cfg.force_z_scale_frac * w  # [N]
    fz_lo, fz_hi = (frac * w for frac in cfg.force_z_range_frac)  # [N]
    fxy_max = cfg.mu * fz_hi  # the friction cone at the largest F_z [N]
    f = ((cfg.freq_range[0] - cfg.freq_shift) / cfg.freq_scale, (cfg.freq_range[1] - cfg.freq_shift) / cfg.freq_scale)
    d = ((cfg.duty_range[0] - cfg.duty_shift) / cfg.duty_scale, (cfg.duty_range[1] - cfg.duty_shift) / cfg.duty_scale)
    px = (cfg.foothold_x_range[0] / p_scale, cfg.foothold_x_range[1] / p_scale)
    py = (cfg.foothold_y_range[0] / p_scale, cfg.foothold_y_range[1] / p_scale)
    fxy = (-fxy_max / fxy_scale, fxy_max / fxy_scale)
    # F_z shift = m g / max(n, 1): the lowest raw value with one leg in stance, the highest with four
    fz = ((fz_lo - w / 1) / fz_scale, (fz_hi - w / C.NUM_LEGS) / fz_scale)
    per_entry = [f] * 4 + [d] * 4 + [px, py] * 4 + [fxy, fxy, fz] * 4
    assert len(per_entry) == ACTION_DIM
    low, high = np.array(per_entry, dtype=np.float64).T
    return low, high


def action_space(cfg: LatentActionConfig) -> gymnasium.spaces.Box:
    """One robot's latent action: ``Box((28,), float32)`` over :func:`action_bounds`."""
    low, high = action_bounds(cfg)
    return gymnasium.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def _scan_bounds(env) -> tuple[float, float]:
    return -env.scene.scan_cfg.clip, env.scene.scan_cfg.clip


TERM_BOUNDS: dict[Callable, Callable[[object], tuple[float, float] | Bounds]] = {
    obs_mdp.projected_gravity: lambda env: (-1.0, 1.0),  # a unit vector
    obs_mdp.leg_phase: lambda env: (0.0, 1.0),  # [0, 1)
    obs_mdp.foot_contact: lambda env: (0.0, 1.0),  # 0 or 1
    obs_mdp.height_scan: _scan_bounds,  # clipped to [-clip, clip] [m]
    obs_mdp.last_action: lambda env: action_bounds(env.action_manager.cfg),  # the applied (clipped) action
}
"""Observation term function -> env -> (low, high) of its values before noise (scalars or (D,) arrays).
Keyed by function, not term name: a task may name a term as it likes."""


def group_bounds(env, group: str) -> Bounds:
    """(D_group,) low and high of one observation group, noise and float32 margin included."""
    manager = env.observation_manager
    lows, highs = [], []
    for term in manager.groups[group]:
        dim = manager.dims[group][term.name]
        bounds = TERM_BOUNDS.get(term.func)
        lo, hi = bounds(env) if bounds is not None else (-np.inf, np.inf)
        lo = np.broadcast_to(np.asarray(lo, np.float64), (dim,))
        hi = np.broadcast_to(np.asarray(hi, np.float64), (dim,))
        noise = term.extra["noise"] * manager.noise_scale[group]  # U(-noise, noise) added by the manager
        lows.append(lo - noise - FLOAT32_MARGIN * np.maximum(1.0, np.abs(lo)))
        highs.append(hi + noise + FLOAT32_MARGIN * np.maximum(1.0, np.abs(hi)))
    return np.concatenate(lows), np.concatenate(highs)


def observation_space(env) -> gymnasium.spaces.Dict:
    """One robot's observation: ``Dict({group: Box((D_group,), float32)})`` in the env's group order."""
    boxes = {}
    for group in env.observation_manager.groups:
        low, high = group_bounds(env, group)
        boxes[group] = gymnasium.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
    return gymnasium.spaces.Dict(boxes)
