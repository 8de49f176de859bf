"""Latent action (f, d, p, F): layout, normalisation, clipping, frames (thesis 4.2.2, 4.3.4, Tables 1 and 5).

The policy (or the MPC) outputs a raw 28-vector, leg order FL, FR, RL, RR:

    [ f(4) | d(4) | p_xy(4 x 2), leg-major | F_xyz(4 x 3), leg-major ]
      0..3   4..7   8..15 (FL p_x, FL p_y, FR p_x, ...)   16..27 (FL F_x, FL F_y, FL F_z, FR F_x, ...)

Each value is ``shift + scale * raw`` (Table 5), then clipped to Table 1 and the friction cone,
then mapped from the horizontal frame H (yaw of the base, parallel to the ground plane) to the
world frame. See docs/latent_action.md for the tables and a worked example; the tables' numbers are a
:class:`~dls_quadruped.control.action_config.LatentActionConfig`.

Everything is pure torch, batched over any leading dimensions (B robots, or B x M x N for
the sampling MPC), and keeps the dtype and device of its inputs; only
:class:`ActionInterface` insists on a (B, 28) batch because it is the env's entry point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.robots.aliengo import constants as C

ACTION_DIM = 28
ACTION_COMPONENT_NAMES: tuple[str, ...] = (
    tuple(f"f[{leg}]" for leg in C.LEG_NAMES)
    + tuple(f"d[{leg}]" for leg in C.LEG_NAMES)
    + tuple(f"p_{ax}[{leg}]" for leg in C.LEG_NAMES for ax in "xy")
    + tuple(f"F_{ax}[{leg}]" for leg in C.LEG_NAMES for ax in "xyz")
)
"""Name of each of the 28 raw action entries, e.g. ``"F_z[RL]"`` is index 16 + 3 * 2 + 2 = 24."""
ACTION_GROUPS: tuple[tuple[str, slice], ...] = (("f", slice(0, 4)), ("d", slice(4, 8)), ("p", slice(8, 16)),
                                                 ("F", slice(16, 28)))
"""(name, index range) of each component of the 28-vector: frequency, duty, foothold offset, force."""
F_Z_INDICES = tuple(16 + 3 * leg + 2 for leg in range(C.NUM_LEGS))
"""Indices of F_z (FL, FR, RL, RR) in the 28-vector."""
RAW_LIMIT = 1e6
"""Raw entries are clamped to +-RAW_LIMIT before use: far beyond the few tens that reach every limit of Table 1,
and small enough that the squared violation, the action rate and the friction-cone norm stay finite in float32
(1e20 is clipped and penalised as 1e6 is, not as an overflow to inf that a reward reads as 0)."""

TerrainHeightFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""height_w = fn(x_w, y_w): ground height [m] under world points; inputs and output share any shape."""


def flat_ground(x_w: torch.Tensor, y_w: torch.Tensor) -> torch.Tensor:
    """Terrain height function of a flat ground plane at z = 0."""
    return torch.zeros_like(x_w)


@dataclass
class LatentAction:
    """One latent action per robot, physical units, horizontal frame H. Leading dims (...) = (B,) usually.

    Attributes:
        f: (..., 4) [Hz] step frequency per leg.
        d: (..., 4) duty cycle per leg (stance fraction of the cycle).
        p_h: (..., 4, 2) [m] touch-down offset (x, y) from the nominal foothold, frame H.
        F_h: (..., 4, 3) [N] ground-reaction force on the foot, frame H.
    """

    f: torch.Tensor
    d: torch.Tensor
    p_h: torch.Tensor
    F_h: torch.Tensor

    def to_vector(self) -> torch.Tensor:
        """Flatten to the (..., 28) layout [f, d, p_xy leg-major, F_xyz leg-major]."""
        lead = self.f.shape[:-1]
        return torch.cat([self.f, self.d, self.p_h.reshape(*lead, 8), self.F_h.reshape(*lead, 12)], dim=-1)

    @classmethod
    def from_vector(cls, vec: torch.Tensor) -> LatentAction:
        """Inverse of :meth:`to_vector`; vec: (..., 28) in physical units."""
        if vec.shape[-1:] != (ACTION_DIM,):
            raise ValueError(f"latent action vector must have shape (..., {ACTION_DIM}), got {tuple(vec.shape)}")
        lead = vec.shape[:-1]
        return cls(vec[..., 0:4], vec[..., 4:8], vec[..., 8:16].reshape(*lead, 4, 2),
                   vec[..., 16:28].reshape(*lead, 4, 3))


@constant_cache
def scale_vector(cfg: LatentActionConfig, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Table 5 scales as a (28,) vector in the action layout; built once per (cfg, dtype, device) and shared, so
    read-only (an action step uploads no constants)."""
    w = cfg.weight
    p_s = cfg.foothold_scale_frac * cfg.hip_height  # [m]
    fxy_s = cfg.force_xy_scale_frac * w  # [N]
    fz_s = cfg.force_z_scale_frac * w  # [N]
    values = [cfg.freq_scale] * 4 + [cfg.duty_scale] * 4 + [p_s] * 8 + [fxy_s, fxy_s, fz_s] * 4
    return torch.tensor(values, dtype=dtype, device=device)


@constant_cache
def _shift_parts(cfg: LatentActionConfig, dtype: torch.dtype,
                 device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(28,) shifts without the F_z term, and the (28,) indicator of the F_z entries (shared, read-only)."""
    base = torch.tensor([cfg.freq_shift] * 4 + [cfg.duty_shift] * 4 + [0.0] * 20, dtype=dtype, device=device)
    is_fz = torch.zeros(ACTION_DIM, dtype=dtype, device=device)
    is_fz[list(F_Z_INDICES)] = 1.0
    return base, is_fz


def _shift(
    cfg: LatentActionConfig, num_stance: torch.Tensor | float, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """Table 5 shifts as a (..., 28) vector; the F_z shift m g / max(n, 1) depends on the stance count."""
    base, is_fz = _shift_parts(cfg, dtype, device)
    n = torch.as_tensor(num_stance, device=device).to(dtype).clamp_min(1.0)
    fz_shift = (cfg.weight / n).unsqueeze(-1)  # (..., 1) [N]
    return base + fz_shift * is_fz


@constant_cache
def _nominal_foothold(cfg: LatentActionConfig, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(4, 2) [m] ``cfg.nominal_foothold_b`` as a tensor (shared, read-only)."""
    return torch.tensor(cfg.nominal_foothold_b, dtype=dtype, device=device)


def denormalise(raw: torch.Tensor, num_stance: torch.Tensor | float, cfg: LatentActionConfig) -> LatentAction:
    """Raw network output -> physical latent action: value = shift + scale * raw (Table 5).

    Args:
        raw: (..., 28) normalised action.
        num_stance: (...) or scalar, number of legs in stance (F_z shift = m g / max(n, 1)).
        cfg: constants.

    Returns:
        LatentAction with leading dims (...), not clipped.
    """
    shift = _shift(cfg, num_stance, raw.dtype, raw.device)
    return LatentAction.from_vector(shift + scale_vector(cfg, raw.dtype, raw.device) * raw)


def normalise(action: LatentAction, num_stance: torch.Tensor | float, cfg: LatentActionConfig) -> torch.Tensor:
    """Exact inverse of :func:`denormalise`: raw = (value - shift) / scale, (..., 28)."""
    vec = action.to_vector()
    return (vec - _shift(cfg, num_stance, vec.dtype, vec.device)) / scale_vector(cfg, vec.dtype, vec.device)


def clip(action: LatentAction, cfg: LatentActionConfig) -> tuple[LatentAction, torch.Tensor]:
    """Clip to Table 1 and the friction cone; also return the violation in raw units.

    f, d, p_x, p_y and F_z are clamped to their ranges; then F_xy is scaled down radially
    (direction kept) to ||F_xy|| <= mu F_z using the clamped F_z.

    Returns:
        clipped: LatentAction, same shapes.
        violation: (..., 28) ``raw - normalise(clipped)`` = (value - clipped) / scale; zero for
            entries inside their limits. The shift cancels, so no stance count is needed.
    """
    f = action.f.clamp(*cfg.freq_range)
    d = action.d.clamp(*cfg.duty_range)
    p_x = action.p_h[..., 0].clamp(*cfg.foothold_x_range)
    p_y = action.p_h[..., 1].clamp(*cfg.foothold_y_range)
    fz_lo, fz_hi = (frac * cfg.weight for frac in cfg.force_z_range_frac)
    f_z = action.F_h[..., 2].clamp(fz_lo, fz_hi)
    f_xy = action.F_h[..., :2]
    norm_xy = torch.linalg.vector_norm(f_xy, dim=-1)  # (..., 4) [N]
    limit = cfg.mu * f_z
    # factor = min(1, mu F_z / ||F_xy||); the where avoids 0/0 for a zero tangential force.
    factor = torch.where(norm_xy > limit, limit / norm_xy.clamp_min(torch.finfo(norm_xy.dtype).tiny), 1.0)
    f_xy = f_xy * factor.unsqueeze(-1)
    clipped = LatentAction(f, d, torch.stack([p_x, p_y], dim=-1), torch.cat([f_xy, f_z.unsqueeze(-1)], dim=-1))
    violation = (action.to_vector() - clipped.to_vector()) / scale_vector(cfg, f.dtype, f.device)
    return clipped, violation


def to_world(action: LatentAction, base_pos_w: torch.Tensor, base_yaw: torch.Tensor,
             terrain_height_fn: TerrainHeightFn, cfg: LatentActionConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Touch-down targets and forces in the world frame.

    p_td_w.xy = base_xy + Rz(yaw) (nominal_xy + p_h); p_td_w.z = terrain(p_td_w.xy) + foot radius
    (sphere centre touching the ground); F_w = Rz(yaw) F_h (H is horizontal, so z is unchanged).

    Args:
        action: LatentAction with leading dims (...).
        base_pos_w: (..., 3) [m] base position, world frame.
        base_yaw: (...) [rad] base yaw (the rotation from H to world).
        terrain_height_fn: ground height under world (x, y).
        cfg: constants.

    Returns:
        p_td_w: (..., 4, 3) [m]; F_w: (..., 4, 3) [N]; world frame.
    """
    dtype, device = action.p_h.dtype, action.p_h.device
    c, s = torch.cos(base_yaw).unsqueeze(-1), torch.sin(base_yaw).unsqueeze(-1)  # (..., 1)
    nominal = _nominal_foothold(cfg, dtype, device)  # (4, 2)
    q_h = nominal + action.p_h  # (..., 4, 2) foothold relative to the base, frame H
    x_w = base_pos_w[..., 0:1] + c * q_h[..., 0] - s * q_h[..., 1]  # (..., 4)
    y_w = base_pos_w[..., 1:2] + s * q_h[..., 0] + c * q_h[..., 1]
    z_w = terrain_height_fn(x_w, y_w) + cfg.foot_radius
    p_td_w = torch.stack([x_w, y_w, z_w], dim=-1)
    fx, fy = action.F_h[..., 0], action.F_h[..., 1]
    F_w = torch.stack([c * fx - s * fy, s * fx + c * fy, action.F_h[..., 2]], dim=-1)
    return p_td_w, F_w


@dataclass
class LowLevelReferences:
    """What the low-level controller needs from one latent action, world frame.

    Attributes:
        f: (B, 4) [Hz] clipped step frequency.
        d: (B, 4) clipped duty cycle.
        p_td_w: (B, 4, 3) [m] touch-down targets (foot-sphere centres), world frame.
        F_w: (B, 4, 3) [N] stance ground-reaction forces, world frame.
        action: clipped LatentAction (frame H), kept for observations/logging.
        violation: (B, 28) clipping violation in raw units, for the action-limit reward.
    """

    f: torch.Tensor
    d: torch.Tensor
    p_td_w: torch.Tensor
    F_w: torch.Tensor
    action: LatentAction
    violation: torch.Tensor


def finite_entries(raw: torch.Tensor, cfg: LatentActionConfig) -> torch.Tensor:
    """(..., 28) bool: the entry and its physical value scale * raw are finite (-3e38 is a finite raw entry, but
    its force overflows float32 to -inf: it is refused as an inf is)."""
    return torch.isfinite(raw * scale_vector(cfg, raw.dtype, raw.device))


def validate_raw(raw: torch.Tensor, check_finite: bool = True, cfg: LatentActionConfig | None = None) -> None:
    """Raise (ValueError, TypeError for a non-tensor) unless raw is a finite (B, 28) tensor, naming what is wrong.

    ``check_finite=False`` checks the type and shape only: the finiteness check reads the tensor back to the
    host (a device synchronisation), which a caller that has already replaced non-finite rows skips. With
    ``cfg`` (raw network units), an entry whose physical value overflows (:func:`finite_entries`) is refused too."""
    if not isinstance(raw, torch.Tensor):
        raise TypeError(f"latent action must be a torch.Tensor of shape (B, {ACTION_DIM}), got {type(raw).__name__}")
    if raw.dim() != 2 or raw.shape[1] != ACTION_DIM:
        raise ValueError(
            f"latent action must have shape (B, {ACTION_DIM}) = [f(4), d(4), p_xy(4x2), F_xyz(4x3)], "
            f"got {tuple(raw.shape)}"
        )
    if not check_finite:
        return
    bad = ~(torch.isfinite(raw) if cfg is None else finite_entries(raw, cfg))
    if bad.any():
        robots = torch.nonzero(bad.any(dim=1)).flatten().tolist()
        comps = [ACTION_COMPONENT_NAMES[i] for i in torch.nonzero(bad.any(dim=0)).flatten().tolist()]
        shown = robots if len(robots) <= 20 else robots[:20] + [f"... ({len(robots)} robots)"]
        what = "NaN/inf" if cfg is None else "NaN/inf, or inf once scaled to physical units"
        raise ValueError(f"latent action has non-finite values ({what}) for robots {shown} in components {comps}; "
                         "every entry must be finite")


class ActionInterface:
    """The action pipeline: raw (B, 28) -> validated -> denormalised -> clipped -> world references."""

    def __init__(self, cfg: LatentActionConfig | None = None, terrain_height_fn: TerrainHeightFn = flat_ground):
        self.cfg = cfg if cfg is not None else LatentActionConfig()
        self.terrain_height_fn = terrain_height_fn

    def __call__(
        self, raw: torch.Tensor, num_stance: torch.Tensor, base_pos_w: torch.Tensor, base_yaw: torch.Tensor,
        check_finite: bool = True,
    ) -> LowLevelReferences:
        """Process one batch of raw actions.

        Args:
            raw: (B, 28) normalised action (network output).
            num_stance: (B,) legs currently in stance (sets the F_z shift m g / n).
            base_pos_w: (B, 3) [m] base position, world frame.
            base_yaw: (B,) [rad] base yaw.
            check_finite: refuse non-finite entries (a host read of ``raw``); False where the caller already
                replaced them (``LocomotionEnv.check_actions``).

        Raises:
            ValueError: wrong shape or non-finite entries (names robots and components).
        """
        validate_raw(raw, check_finite, self.cfg)
        self._check_state(raw.shape[0], num_stance, base_pos_w, base_yaw)
        raw = raw.clamp(-RAW_LIMIT, RAW_LIMIT)
        return self._references(denormalise(raw, num_stance, self.cfg), base_pos_w, base_yaw)

    def from_physical(self, action: LatentAction, base_pos_w: torch.Tensor,
                      base_yaw: torch.Tensor) -> LowLevelReferences:
        """Same pipeline for an action already in physical units (e.g. the balance controller's).

        Args:
            action: LatentAction with leading dim (B,), frame H, not yet clipped.
            base_pos_w: (B, 3) [m]; base_yaw: (B,) [rad].
        """
        vec = action.to_vector()
        validate_raw(vec)
        batch = vec.shape[0]
        self._check_state(batch, torch.zeros(batch), base_pos_w, base_yaw)
        return self._references(action, base_pos_w, base_yaw)

    @staticmethod
    def _check_state(batch: int, num_stance: torch.Tensor, base_pos_w: torch.Tensor, base_yaw: torch.Tensor) -> None:
        for name, value, shape in (("num_stance", num_stance, (batch,)), ("base_pos_w", base_pos_w, (batch, 3)),
                                   ("base_yaw", base_yaw, (batch,))):
            if tuple(value.shape) != shape:
                raise ValueError(f"{name} must have shape {shape} for a batch of {batch} actions, got "
                                 f"{tuple(value.shape)}")

    def _references(self, action: LatentAction, base_pos_w: torch.Tensor, base_yaw: torch.Tensor) -> LowLevelReferences:
        """Clip, then map to the world frame."""
        clipped, violation = clip(action, self.cfg)
        dtype = clipped.f.dtype
        p_td_w, F_w = to_world(clipped, base_pos_w.to(dtype), base_yaw.to(dtype), self.terrain_height_fn, self.cfg)
        return LowLevelReferences(clipped.f, clipped.d, p_td_w, F_w, clipped, violation)
