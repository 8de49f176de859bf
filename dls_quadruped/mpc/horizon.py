"""A policy's horizon action scored by the sampling MPC's own model and cost (thesis 5.3).

A horizon policy outputs an encoded horizon of latent actions in the action manager's raw units, like a
distilled student (``learning.student``): ``(f_0, d_0) + enc_p + enc_F`` (:mod:`encodings`). Two uses:

* the env applies its first action, :func:`first_raw_action` -- step 0 of the MPC's own decoding
  (``encodings.decode``; for a spline block theta_0, the value at x_0 = 0);
* a reward scores the whole horizon as the MPC scores a sample, :func:`score_horizon`: the raw output mapped to
  the MPC's units (``warm_start.from_student``) and handed, with the SRBD state and the references the closed loop
  builds (``inputs.mpc_inputs``), to the controller's cost kernel as a one-sample solve's only warm start (sample 0
  of a group is its warm start unperturbed: clipped to the encoded box, decoded with the robot's gait phase, rolled
  out, costed). The scoring config (:func:`horizon_sampler_config`) has the controller's state weights Q and R = 0,
  so the kernel's J is the state cost alone. Its split by term (``MPCResult.state_terms``' reference rollout,
  ``cost.rollout_step_costs_and_terms``) is computed on request.

    cfg = horizon_sampler_config(EncodingConfig("first", "spline", 10), dt=0.02, action=LatentActionConfig())
    score = score_horizon(raw_horizon, env.state, command, com_height=0.404, cfg=cfg, terms=True)
    score.state_cost        # (B,) sum_k (x_{k+1} - x_ref)^T Q (x_{k+1} - x_ref)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import CostWeights, EncodingConfig, SamplerConfig
from dls_quadruped.mpc.cost import STATE_TERMS, rollout_step_costs_and_terms
from dls_quadruped.mpc.encodings import decode, encoded_dim
from dls_quadruped.mpc.inputs import mpc_inputs
from dls_quadruped.mpc.kernel import KernelInputs
from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY
from dls_quadruped.mpc.samples import decode_samples, sample_encoded
from dls_quadruped.mpc.srbd import SRBDModel, robot_srbd_model

__all__ = ["TERM_NAMES", "EncodingConfig", "HorizonScore", "encoded_dim", "first_raw_action", "horizon_inputs",
           "horizon_sampler_config", "score_horizon", "state_terms"]

TERM_NAMES = tuple(STATE_TERMS)
"""Names of the state-cost terms, in the order of :attr:`HorizonScore.state_terms` (Table 9)."""


@functools.lru_cache(maxsize=16)
def horizon_sampler_config(encoding: EncodingConfig, dt: float, action: LatentActionConfig,
                           kernel: str = "cpp") -> SamplerConfig:
    """The MPC settings that score one horizon: the encoding, its spacing ``dt`` [s], the latent-action limits
    ``action`` (the env's), one sample, the controller's ``kernel`` and state weights Q (Table 9) with R = 0
    (Table 10's foothold weight off: the kernel's J is then the state cost alone)."""
    return SamplerConfig(num_samples=1, horizon=encoding.horizon, dt=float(dt), encoding_p=encoding.p,
                         encoding_F=encoding.F, constrained_fit=encoding.constrained_fit, action=action,
                         kernel=kernel, weights=CostWeights(foothold_xy=0.0))


def first_raw_action(raw_horizon: torch.Tensor, encoding: EncodingConfig) -> torch.Tensor:
    """(B, D) encoded horizon in raw action units -> (B, 28) its first raw action (step 0 of ``encodings.decode``).

    Decoding is linear per scalar, so step 0 of the raw units' decoding is the raw first action.
    """
    return decode(raw_horizon, encoding)[..., 0, :]


@dataclass
class HorizonScore:
    """The MPC's state cost of B horizons.

    Attributes:
        state_cost: (B,) sum over the N steps of the state cost of x_{k+1} (the evaluations' "state rollout cost"),
            from the config's kernel.
        state_terms: (B, 9) the state cost split by term (``TERM_NAMES``), summing to ``state_cost``, from the
            reference rollout; None unless asked for.
    """

    state_cost: torch.Tensor
    state_terms: torch.Tensor | None = None


def horizon_inputs(raw_horizon: torch.Tensor, state: RobotState, command: torch.Tensor, com_height: float,
                   cfg: SamplerConfig, model: SRBDModel | None = None) -> KernelInputs:
    """The kernel inputs, on the CPU, of a one-sample solve whose warm start is each robot's horizon (flat ground at
    z = 0).

    Args:
        raw_horizon: (B, D) encoded horizon in the action manager's raw units (a student's output).
        state: the robots' state when the action was chosen; command: (B, 3) (v_x, v_y [m/s], frame H; yaw
            rate [rad/s]) at that time.
        com_height: [m] CoM height reference above the ground (``ControllerConfig.com_height``), in [0.1, 0.6].
        cfg: :func:`horizon_sampler_config`; model: SRBD parameters (default: the robot's).

    Raises:
        ValueError: ``raw_horizon`` is not (B, D) for the encoding, or ``com_height`` is out of range.
    """
    model = model or robot_srbd_model()
    dim = encoded_dim(cfg.encoding)
    b = state.base_pos_w.shape[0]
    if raw_horizon.dim() != 2 or tuple(raw_horizon.shape) != (b, dim):
        raise ValueError(f"raw_horizon must have shape (B, D) = ({b}, {dim}) for encoding {cfg.encoding_p}-"
                         f"{cfg.encoding_F} H={cfg.horizon}, got {tuple(raw_horizon.shape)}")
    if not 0.1 <= com_height <= 0.6:
        raise ValueError(f"com_height (the MPC's CoM height reference) must be in [0.1, 0.6] m, got {com_height!r}")
    # the C++ kernel computes on the CPU (as in the closed loop, whose MPC runs where its kernel runs); mpc_inputs
    # builds its constants on the CPU too
    dev = torch.device("cpu")
    state = state if state.base_pos_w.device == dev else state.to(dev)
    encoded = warm_start.from_student(raw_horizon.to(dev, torch.float32), cfg)
    # the reference footholds only enter the input cost, which R = 0 switches off: the nominal ones
    srbd, refs, frame = mpc_inputs(state, command.to(dev), torch.zeros(b, 4, 2), float(com_height), cfg, model)
    return KernelInputs(
        seed=torch.zeros((), dtype=torch.long, device=dev), warm_starts=encoded[:, None, :],
        group=torch.zeros(1, dtype=torch.long, device=dev), perturb=torch.zeros(1, device=dev),
        x0=srbd.as_vector().to(dev), phase=state.phase.to(dev, torch.float32), base_xy_w=frame["base_xy_w"].to(dev),
        base_yaw=frame["base_yaw"].to(dev), terrain_z_w=torch.zeros(b, 4, device=dev), refs=refs.to(dev))


def state_terms(inp: KernelInputs, cfg: SamplerConfig, model: SRBDModel) -> torch.Tensor:
    """(B, 9) the state cost of the one-sample solve ``inp`` by term, from the reference rollout (eager torch,
    ``MPCResult.state_terms``' code): sample 0 drawn (no noise, clipped), decoded, rolled out, costed."""
    b = inp.x0.shape[0]
    idx = torch.zeros(b, 1, dtype=torch.long, device=inp.x0.device)
    sample = sample_encoded(inp.seed, inp.warm_starts, inp.group, inp.perturb, idx, cfg)
    dec = decode_samples(sample, inp.phase, inp.base_xy_w, inp.base_yaw, inp.terrain_z_w, cfg)
    _, terms = rollout_step_costs_and_terms(inp.x0, dec["contact"], dec["foot_target_w"], dec["force_w"], inp.refs,
                                            model, cfg.weights, cfg.dt)
    return terms[:, 0]


def score_horizon(raw_horizon: torch.Tensor, state: RobotState, command: torch.Tensor, com_height: float,
                  cfg: SamplerConfig, model: SRBDModel | None = None, terms: bool = False) -> HorizonScore:
    """The MPC's state cost of each robot's horizon action from its state (:func:`horizon_inputs`): the config's
    kernel for the total, the reference rollout for the split by term when ``terms``."""
    model = model or robot_srbd_model()
    inp = horizon_inputs(raw_horizon, state, command, com_height, cfg, model)
    cost = KERNEL_REGISTRY.get(cfg.kernel)(inp, cfg, model)[:, 0]
    return HorizonScore(cost, state_terms(inp, cfg, model) if terms else None)
