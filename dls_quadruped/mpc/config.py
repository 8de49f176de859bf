"""Frozen configuration of the sampling MPC (thesis 3.2, Tables 9, 10, 13).

Three small dataclasses, all frozen and hashable (the compiled kernel is cached per config):

* :class:`CostWeights` - diagonals of Q (Table 9) and R (Table 10);
* :class:`EncodingConfig` - how a horizon of latent actions is encoded (thesis 5.1);
* :class:`SamplerConfig` - samples, horizon, dt, sigmas, kernel choice, and the latent-action
  limits (reused from :class:`dls_quadruped.control.latent_action.LatentActionConfig`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY

ENCODING_KINDS = ("discrete", "spline", "first")
KERNELS = KERNEL_REGISTRY.as_mapping()
"""The cost kernels by name (a live view of ``KERNEL_REGISTRY``): ``fast``, ``reference``, ``cpp``, ``warp``."""


def _check_from_dict(cls: type, values: dict) -> None:
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys {unknown}; allowed: {sorted(allowed)}")


def _is_real(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class CostWeights:
    """Diagonal cost weights (Tables 9 and 10); entries not listed there are 0.

    State weights act on x = [p_c(3), v_c(3), Phi(3), omega_b(3), p_f(12)]; the yaw angle and
    the CoM x, y carry weight 0. Rates are penalised on the base-frame angular velocity
    omega_b (Table 9 labels them Euler rates; for a flat base they coincide).

    Attributes:
        z: CoM height vs the desired height [1/m^2].
        vx, vy, vz: CoM velocity (world frame) vs the command.
        roll, pitch: Euler angles vs 0 (flat attitude).
        roll_rate, pitch_rate, yaw_rate: omega_b vs (0, 0, commanded yaw rate).
        foothold_xy: R weight on the touch-down target (x, y, world) vs the reference foothold.
    """

    z: float = 111500.0
    vx: float = 5000.0
    vy: float = 5000.0
    vz: float = 200.0
    roll: float = 11200.0
    pitch: float = 11200.0
    roll_rate: float = 20.0
    pitch_rate: float = 20.0
    yaw_rate: float = 200.0
    foothold_xy: float = 1000.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if not 0 <= getattr(self, f.name) < math.inf:
                raise ValueError(f"CostWeights.{f.name} must be >= 0 and finite, got {getattr(self, f.name)!r}")

    def q_diag(self) -> tuple[float, ...]:
        """The 24 diagonal entries of Q in state order [p, v, Phi, omega, p_f]."""
        return (0.0, 0.0, self.z, self.vx, self.vy, self.vz, self.roll, self.pitch, 0.0,
                self.roll_rate, self.pitch_rate, self.yaw_rate) + (0.0,) * 12

    def r_diag(self) -> tuple[float, ...]:
        """The 24 diagonal entries of R in input order [p_td(4x3), F(4x3)] (Table 10)."""
        return (self.foothold_xy, self.foothold_xy, 0.0) * 4 + (0.0,) * 12


@dataclass(frozen=True)
class EncodingConfig:
    """Encoding of a horizon of H latent actions (thesis 5.1, Table 13).

    Attributes:
        p: encoding of the touch-down offsets p_xy: "discrete" | "spline" | "first".
        F: encoding of the forces F_xyz: "discrete" | "spline" | "first".
        horizon: H, number of actions (= MPC steps N when used by the sampler).
        constrained_fit: spline fit exact at the first sample (thesis A.3) instead of plain
            least squares (A.2.9).
    """

    p: str = "first"
    F: str = "spline"
    horizon: int = 10
    constrained_fit: bool = True

    def __post_init__(self) -> None:
        for name in ("p", "F"):
            if getattr(self, name) not in ENCODING_KINDS:
                raise ValueError(f"EncodingConfig.{name} must be one of {ENCODING_KINDS}, got {getattr(self, name)!r}")
        if not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"EncodingConfig.horizon must be an int >= 1, got {self.horizon!r}")
        if "spline" in (self.p, self.F) and self.horizon < 4:
            raise ValueError(
                f"EncodingConfig.horizon must be >= 4 with a spline encoding (4 parameters are fitted), "
                f"got {self.horizon}"
            )

    @classmethod
    def from_dict(cls, values: dict) -> EncodingConfig:
        """Build from a dict; unknown keys raise naming the allowed ones."""
        _check_from_dict(cls, values)
        return cls(**values)


@dataclass(frozen=True)
class SamplerConfig:
    """Sampling MPC settings (thesis 3.2 and 7.3).

    Attributes:
        num_samples: M, samples per robot (all warm-start groups together).
        horizon: N, rollout steps; the encoding horizon H equals N.
        dt: [s] SRBD integration step and spacing of the encoded actions.
        encoding_p, encoding_F: "discrete" | "spline" | "first" for p and F.
        constrained_fit: spline fits exact at the first sample (A.3).
        sigma_f: [Hz] std of the step-frequency noise; 0 switches f optimisation off.
        sigma_d: std of the duty-cycle noise.
        sigma_p: [m] std of the touch-down offset noise (per encoded parameter).
        sigma_F: [N] std of the force noise (per encoded parameter).
        mpc_period: [s] time between two solves (100 Hz); the naive warm start is shifted by
            mpc_period / dt horizon steps.
        kernel: "cpp" (default: hand-written C++/OpenMP kernel built at first use; CPU only: on CUDA the solve
            runs "warp" when Warp is installed, else "fast"; "fast" too if it cannot be built), "warp" (one Warp
            kernel, a thread per sample, and the solve without host reads, ``mpc/warp_solve.py``; CUDA or Warp's
            CPU device), "fast" (torch.compile'd fused kernel, eager fallback) or "reference" (plain eager).
        weights: cost weights.
        action: latent-action limits (Table 1), nominal footholds, mass, mu.
        switching_cost: [cost units of eq. 3.2.1] with several warm starts, added to the cost of every sample
            outside the robot's previous winning group before the argmin (:mod:`arbitration`); 0 = off.
        group_cost_smoothing: beta in [0, 1): with several warm starts, the groups compete with a running
            average of their best cost, A_g <- (1 - beta) J_g + beta A_g (:mod:`arbitration`); 0 = off.
    """

    num_samples: int = 10000
    horizon: int = 10
    dt: float = 0.02
    encoding_p: str = "first"
    encoding_F: str = "spline"
    constrained_fit: bool = True
    sigma_f: float = 0.02
    sigma_d: float = 0.05
    sigma_p: float = 0.02
    sigma_F: float = 10.0
    mpc_period: float = 0.01
    kernel: str = "cpp"
    weights: CostWeights = field(default_factory=CostWeights)
    action: LatentActionConfig = field(default_factory=LatentActionConfig)
    switching_cost: float = 0.0
    group_cost_smoothing: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.num_samples, int) or self.num_samples < 1:
            raise ValueError(f"SamplerConfig.num_samples must be an int >= 1, got {self.num_samples!r}")
        if not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"SamplerConfig.horizon must be an int >= 1, got {self.horizon!r}")
        for name in ("dt", "mpc_period"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"SamplerConfig.{name} must be > 0 and finite, got {getattr(self, name)!r}")
        for name in ("sigma_f", "sigma_d", "sigma_p", "sigma_F"):
            if not 0 <= getattr(self, name) < math.inf:  # inf noise turns every sample into NaN/inf
                raise ValueError(
                    f"SamplerConfig.{name} must be >= 0 and finite (0 switches that variable's optimisation off), "
                    f"got {getattr(self, name)!r}"
                )
        if not _is_real(self.switching_cost) or not 0 <= self.switching_cost < math.inf:
            raise ValueError(f"SamplerConfig.switching_cost must be >= 0 and finite (cost units of eq. 3.2.1; "
                             f"0 switches it off), got {self.switching_cost!r}")
        if not _is_real(self.group_cost_smoothing) or not 0 <= self.group_cost_smoothing < 1:
            raise ValueError(f"SamplerConfig.group_cost_smoothing must be in [0, 1) (weight of the previous running "
                             f"group cost; 0 switches it off), got {self.group_cost_smoothing!r}")
        if self.kernel not in KERNEL_REGISTRY:
            raise ValueError(f"SamplerConfig.kernel must be one of {KERNEL_REGISTRY.names()}, got {self.kernel!r}")
        _ = self.encoding  # validates the encoding kinds and horizon

    @property
    def arbitrates(self) -> bool:
        """A switching cost or a running group cost is on (a solve with several warm starts arbitrates)."""
        return self.switching_cost > 0 or self.group_cost_smoothing > 0

    @property
    def encoding(self) -> EncodingConfig:
        """The encoding of the sampled horizon (H = N)."""
        return EncodingConfig(self.encoding_p, self.encoding_F, self.horizon, self.constrained_fit)

    @classmethod
    def from_dict(cls, values: dict) -> SamplerConfig:
        """Build from a dict (e.g. YAML); nested ``weights``/``action`` dicts allowed; unknown keys raise."""
        _check_from_dict(cls, values)
        values = dict(values)
        if isinstance(values.get("weights"), dict):
            _check_from_dict(CostWeights, values["weights"])
            values["weights"] = CostWeights(**values["weights"])
        if isinstance(values.get("action"), dict):
            values["action"] = LatentActionConfig.from_dict(values["action"])
        return cls(**values)
