"""Model-based baseline (thesis Fig. 1): periodic trot + heuristic footholds + sampling MPC on the forces.

At every MPC step (100 Hz) for B robots:

1. gait: fixed periodic trot (f, d); the MPC's sigma_f = sigma_d = 0;
2. footholds: the heuristic planner of eq. 2.2.4, in the horizontal frame H relative to the
   nominal foothold under the hip::

       p_h = T_stance / 2 * v_ref + sqrt(z_com / g) (v - v_ref),   T_stance = d / f

   (sigma_p = 0: the MPC does not change them; they are also the cost's foothold reference);
3. forces: the sampling MPC searches around the naive warm start alone (the thesis's naive
   controller): the previous solution with its swing-step force offsets zeroed, shifted by one MPC
   period, with the gait and footholds of steps 1-2 written into it. Forces are sampled as offsets
   from gravity compensation m g / (stance legs of each step) (``samples.forces_from_offsets``), so
   this is a meaningful controller on its own. Optionally (``anchor_share > 0``, off in the thesis
   experiments) a share of the samples is drawn around the nominal trot (zero offsets) as well;
4. the first action ``(f, d, p_0, F_0)`` goes to the low-level controller, which runs at 200 Hz
   inside the simulator backend for ``mpc_period / physics_dt`` physics steps (in a ``LocomotionEnv``: the closed
   loop's ``naive_warm_start`` controller, ``closed_loop/mpc_controllers.py``, also the baseline run of
   ``closed_loop/baseline_run.py``).

The solve's inputs (SRBD state, references, frame H, ground) come from ``mpc/inputs.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

from dls_quadruped.control.latent_action import TerrainHeightFn
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.encodings import block_slices, fit_spline
from dls_quadruped.mpc.inputs import heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC
from dls_quadruped.mpc.srbd import com_height_reference


@dataclass(frozen=True)
class BaselineConfig:
    """Model-based baseline settings.

    Attributes:
        freq, duty: periodic trot [Hz], stance fraction.
        com_height: desired CoM height above the ground [m]; default :func:`srbd.com_height_reference` (the
            base at ``constants.BASE_HEIGHT_TARGET``, the RL task's height target, ~0.324 m for the CoM).
        anchor_share: share of the samples drawn around the nominal trot (zero force offsets) besides
            the naive warm start; 0 (default, the thesis's naive controller) = naive warm start alone.
            Before forces were sampled as offsets from gravity compensation, the naive warm start
            alone collapsed the robot within 0.5 s and a 0.2 anchor share was needed.
        sampler: sampling-MPC settings; sigma_f, sigma_d and sigma_p are forced to 0 (forces only).
    """

    freq: float = 1.5
    duty: float = 0.6
    com_height: float = field(default_factory=com_height_reference)
    anchor_share: float = 0.0
    optimise: tuple[str, ...] = ("F",)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)

    def __post_init__(self) -> None:
        if not 0.0 <= self.anchor_share < 1.0:
            raise ValueError(f"BaselineConfig.anchor_share must be in [0, 1), got {self.anchor_share!r}")
        if not (0.0 < self.freq <= 3.0 and 0.0 < self.duty < 1.0):  # 3 Hz: the latent action's clip of f
            raise ValueError(f"the naive trot must have a frequency in (0, 3] Hz and a duty cycle in (0, 1), got "
                             f"{self.freq!r} Hz and {self.duty!r}")
        if not 0.1 <= self.com_height <= 0.6:
            raise ValueError(f"com_height (the MPC's CoM height reference) must be in [0.1, 0.6] m, got "
                             f"{self.com_height!r}")
        check_optimise(self.optimise)

    def forces_only(self) -> SamplerConfig:
        """The sampler config with gait and foothold optimisation switched off."""
        return replace(self.sampler, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)

    def optimised_sampler(self) -> SamplerConfig:
        """The sampler config with sigma = 0 on every variable not in ``optimise`` (thesis 7.3: F only)."""
        return optimised(self.sampler, self.optimise)


OPTIMISABLE = ("f", "d", "p", "F")
"""Variables the sampling MPC can optimise (thesis 7.3.1: F by default; 7.3.5: f and d; 7.3.6: p)."""


def check_optimise(optimise: tuple[str, ...]) -> None:
    """Raise ``ValueError`` unless ``optimise`` is a non-empty tuple of distinct names from ``OPTIMISABLE``."""
    if (not isinstance(optimise, tuple) or not optimise or len(set(optimise)) != len(optimise)
            or any(v not in OPTIMISABLE for v in optimise)):
        raise ValueError(f"optimise must be a non-empty tuple of distinct variables from {OPTIMISABLE}, "
                         f"got {optimise!r}")


def optimised(sampler: SamplerConfig, optimise: tuple[str, ...]) -> SamplerConfig:
    """``sampler`` with sigma = 0 on every variable not in ``optimise``."""
    check_optimise(optimise)
    return replace(sampler, **{f"sigma_{v}": 0.0 for v in OPTIMISABLE if v not in optimise})


def held_footholds_block(p_h: torch.Tensor, sampler: SamplerConfig) -> torch.Tensor:
    """The p block of ``sampler``'s encoding for footholds held over the whole horizon: (B, 4, 2) frame H [m] ->
    (B, Dp) (``first``: the 8 values; ``discrete``: repeated at every step; ``spline``: the constrained fit of the
    constant, exact at step 0)."""
    kind, horizon = sampler.encoding.p, sampler.horizon
    flat = p_h.reshape(p_h.shape[0], 8)
    if kind == "first":
        return flat
    if kind == "discrete":
        return flat.repeat(1, horizon)
    return fit_spline(flat[:, None, :].expand(-1, horizon, 8), constrained=True).reshape(p_h.shape[0], -1)


class ModelBasedBaseline:
    """Trot + heuristic footholds + force-only sampling MPC for B robots (see module docstring)."""

    def __init__(self, num_robots: int, cfg: BaselineConfig = BaselineConfig(), device: str = "cpu", seed: int = 0):
        self.cfg = cfg
        self.sampler_cfg = cfg.optimised_sampler()
        self.mpc = SamplingMPC(self.sampler_cfg, device=device, seed=seed)
        self.num_robots = num_robots
        self.slices = block_slices(self.sampler_cfg.encoding)
        self.default = warm_start.nominal_trot(num_robots, self.sampler_cfg, cfg.freq, cfg.duty)

    def _encode_p(self, p_h: torch.Tensor) -> torch.Tensor:
        """The p block of the encoding for footholds held over the horizon, (B, 4, 2) -> (B, Dp)."""
        return held_footholds_block(p_h, self.sampler_cfg)

    def step(self, state: RobotState, cmd_vel_h: torch.Tensor, ground_z: torch.Tensor | None = None,
             height_fn: TerrainHeightFn | None = None) -> tuple[MPCResult, Refs]:
        """One MPC solve: returns the result (first action in the world frame) and the references used.

        The warm start is the naive one (previous solution shifted); the blocks that are not optimised
        are overwritten with the periodic trot (f, d) and the heuristic footholds (p). An optimised
        block keeps the previous solution's values (the trot and the heuristic footholds at the first solve).
        """
        cfg = self.cfg
        p_h = heuristic_footholds_h(state, cmd_vel_h, cfg)
        p_block = self._encode_p(p_h)
        first = self.mpc.last_result is None
        warm_starts = [self.mpc.naive_warm_start(self.default).clone()]
        proportions: tuple[float, ...] = (1.0,)
        if cfg.anchor_share > 0.0:
            warm_starts.append(self.default.clone())
            proportions = (1.0 - cfg.anchor_share, cfg.anchor_share)
        for w in warm_starts:
            if "f" not in cfg.optimise:
                w[:, self.slices["f"]] = cfg.freq
            if "d" not in cfg.optimise:
                w[:, self.slices["d"]] = cfg.duty
            if "p" not in cfg.optimise or first:
                w[:, self.slices["p"]] = p_block
        srbd, refs, frame = mpc_inputs(state, cmd_vel_h, p_h, cfg.com_height, self.sampler_cfg, self.mpc.model,
                                       ground_z, height_fn)
        result = self.mpc.solve(srbd, refs, warm_starts=warm_starts, proportions=proportions,
                                phase=state.phase, **frame)
        return result, refs
