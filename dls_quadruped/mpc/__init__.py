"""Batched torch sampling MPC: SRBD rollouts, cost, action encodings, warm starts (thesis 3.2, 5.1, Appendices A and C).

Usage (B robots, 100 Hz, the thesis's model-based baseline optimising the forces only)::

    import torch
    from dls_quadruped.mpc import (Refs, SamplerConfig, SamplingMPC, com_height_reference,
                                   srbd_state_from_robot_state, warm_start)

    cfg = SamplerConfig(num_samples=10000, horizon=10, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    mpc = SamplingMPC(cfg, device="cpu", seed=0)
    state = srbd_state_from_robot_state(rs)                         # rs: core.state.RobotState (B robots)
    refs = Refs(com_height_w=torch.full((B,), com_height_reference()), lin_vel_w=cmd[:, :2], yaw_rate=cmd[:, 2],
                foothold_w=heuristic_footholds_w)                    # (B, 4, 3)
    default = warm_start.nominal_trot(B, cfg)                        # (B, D) encoded
    result = mpc.solve(state, refs, warm_starts=[mpc.naive_warm_start(default)], phase=rs.phase)
    result.force_w, result.foot_target_w, result.f, result.d         # first action, world frame
    # several warm starts: warm_starts=[naive, policy_ws], proportions=(0.5, 0.5);
    # result.warm_start_index says which one won, result.fallback flags NaN states.

See docs/mpc.md for the model, frames, the typos resolved and the encodings' grid.
"""

from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import CostWeights, EncodingConfig, SamplerConfig
from dls_quadruped.mpc.cost import Refs, initial_cost, rollout_cost_reference
from dls_quadruped.mpc.encodings import (
    decode,
    decode_parts,
    encode,
    encoded_dim,
    fit_spline,
    shift_encoded,
)
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC
from dls_quadruped.mpc.srbd import (
    SRBDModel,
    SRBDState,
    com_height_reference,
    robot_srbd_model,
    rollout_reference,
    srbd_state_from_base,
    srbd_state_from_robot_state,
)

__all__ = [
    "CostWeights",
    "EncodingConfig",
    "MPCResult",
    "Refs",
    "SRBDModel",
    "SRBDState",
    "SamplerConfig",
    "SamplingMPC",
    "com_height_reference",
    "decode",
    "decode_parts",
    "encode",
    "encoded_dim",
    "fit_spline",
    "initial_cost",
    "robot_srbd_model",
    "rollout_cost_reference",
    "rollout_reference",
    "shift_encoded",
    "srbd_state_from_base",
    "srbd_state_from_robot_state",
    "warm_start",
]
