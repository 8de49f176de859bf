"""``LatentActionConfig``: the latent action's normalisation (Table 5), clipping (Table 1) and frame constants.

A frozen dataclass, validated when built (:meth:`LatentActionConfig.from_dict` for a YAML section names an unknown
key and the allowed ones); :mod:`~dls_quadruped.control.latent_action` maps actions with it, the env's action
manager, the MPC's sampler and the closed loop read it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from dls_quadruped.robots.aliengo import constants as C


def _nominal_foothold_b() -> tuple[tuple[float, float], ...]:
    """Under-hip nominal footholds (x, y) [m] in the base frame, including the lateral thigh offset."""
    return tuple(
        (float(C.HIP_OFFSETS_B[leg, 0]), float(C.HIP_OFFSETS_B[leg, 1] + C.LEG_Y_SIGN[leg] * C.THIGH_OFFSET_Y))
        for leg in range(C.NUM_LEGS)
    )


def _to_tuple(value):
    """Lists (possibly nested) -> tuples; anything else unchanged."""
    return tuple(_to_tuple(v) for v in value) if isinstance(value, (list, tuple)) else value


@dataclass(frozen=True)
class LatentActionConfig:
    """Normalisation (Table 5), clipping (Table 1) and frame constants of the latent action.

    Attributes:
        mass: [kg] robot mass m; weight = m g sets the force scales and the F_z limit.
        gravity: [m/s^2] g.
        hip_height: [m] sets the foothold scale.
        mu: friction coefficient of the friction-cone clip ||F_xy|| <= mu F_z.
        freq_shift, freq_scale: [Hz] f = freq_shift + freq_scale * raw.
        duty_shift, duty_scale: d = duty_shift + duty_scale * raw.
        foothold_scale_frac: p_x, p_y scale as a fraction of hip_height (shift 0).
        force_xy_scale_frac: F_x, F_y scale as a fraction of m g (shift 0).
        force_z_scale_frac: F_z scale as a fraction of m g (shift m g / number of stance legs).
        freq_range: [Hz] clip of f.
        duty_range: clip of d.
        foothold_x_range, foothold_y_range: [m] clip of p_x, p_y around the nominal foothold.
        force_z_range_frac: clip of F_z as fractions of m g.
        step_height: [m] swing apex clearance used with these actions.
        foot_radius: [m] touch-down targets are foot-sphere centres, this far above the ground.
        nominal_foothold_b: per leg (x, y) [m] in the base frame of the nominal foothold
            (p = 0): under the thigh joint, i.e. the hip offset plus the lateral thigh offset,
            which is where the foot of the nominal standing pose lands.
    """

    mass: float = C.TOTAL_MASS
    gravity: float = C.GRAVITY
    hip_height: float = C.HIP_HEIGHT
    mu: float = C.MU
    freq_shift: float = 1.5
    freq_scale: float = 0.2
    duty_shift: float = 0.6
    duty_scale: float = 0.03
    foothold_scale_frac: float = 0.05
    force_xy_scale_frac: float = 0.025
    force_z_scale_frac: float = 0.10
    freq_range: tuple[float, float] = (0.0, 3.0)
    duty_range: tuple[float, float] = (0.0, 1.0)
    foothold_x_range: tuple[float, float] = (-0.10, 0.15)
    foothold_y_range: tuple[float, float] = (-0.10, 0.10)
    force_z_range_frac: tuple[float, float] = (0.0, 1.0)
    step_height: float = 0.06
    foot_radius: float = C.FOOT_RADIUS
    nominal_foothold_b: tuple[tuple[float, float], ...] = _nominal_foothold_b()

    def __post_init__(self) -> None:
        positive = ("mass", "gravity", "hip_height", "mu", "freq_scale", "duty_scale", "foothold_scale_frac",
                    "force_xy_scale_frac", "force_z_scale_frac")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"LatentActionConfig.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("freq_range", "duty_range", "foothold_x_range", "foothold_y_range", "force_z_range_frac"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"LatentActionConfig.{name} must be (low, high) with low <= high, got {(lo, hi)}")
        if len(self.nominal_foothold_b) != C.NUM_LEGS or any(len(p) != 2 for p in self.nominal_foothold_b):
            raise ValueError(
                f"LatentActionConfig.nominal_foothold_b must be 4 (x, y) pairs (FL, FR, RL, RR), "
                f"got {self.nominal_foothold_b!r}"
            )

    @classmethod
    def from_dict(cls, values: dict) -> LatentActionConfig:
        """Build from a dict (e.g. a YAML section); unknown keys raise naming the allowed ones."""
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - allowed)
        if unknown:
            raise ValueError(f"unknown LatentActionConfig keys {unknown}; allowed: {sorted(allowed)}")
        # YAML gives lists; the frozen config holds tuples (hashable, immutable).
        as_tuples = {k: _to_tuple(v) for k, v in values.items()}
        return cls(**as_tuples)

    @property
    def weight(self) -> float:
        """m g [N]."""
        return self.mass * self.gravity
