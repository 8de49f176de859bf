"""The result of one sampling-MPC solve, and the checks both solve paths share.

:class:`MPCResult` is what ``SamplingMPC.solve`` returns, from the torch path (``mpc/sampler.py``) and from
the fused CPU path (``mpc/solve_glue.py``) alike; the input checks (:func:`check_tensor`, :func:`check_phase`)
and the last guard's pieces (:func:`action_finite`, :func:`describe_bad`) are the same functions on both.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class MPCResult:
    """Solution of one solve for B robots (world frame unless noted).

    Attributes:
        f: (B, 4) [Hz] step frequency; d: (B, 4) duty cycle.
        contact: (B, 4) bool, stance flags at step 0.
        foot_target_w: (B, 4, 3) [m] touch-down targets p_0; force_w: (B, 4, 3) [N] forces F_0.
        p_h: (B, 4, 2) [m], F_h: (B, 4, 3) [N]: the same first action in the horizontal frame
            (p relative to the nominal foothold), i.e. the latent-action units.
        best_cost: (B,) rollout cost J of the chosen sample (+inf if every sample diverged).
        best_input_cost: (B,) its input part, sum_k (u_k - u_ref)^T R (u_k - u_ref) (the foothold deviation
            from the reference; +inf for a fallback robot). The state-only rollout cost, what evaluations
            compare, is ``best_cost - best_input_cost`` (:attr:`best_state_cost`).
        initial_cost: (B,) state cost of the current state (thesis 7.3.1).
        best_index: (B,) long, winning sample (-1 for a fallback robot).
        warm_start_index: (B,) long, warm start whose group the winner came from (-1 for a fallback).
        best_encoded: (B, D) winning encoded action (box-clipped; F block = force offsets from gravity
            compensation, ``samples.forces_from_offsets``), for the naive warm start.
        contact_horizon: (B, N, 4) bool, the winner's contact sequence over the horizon (step 0 = ``contact``).
        step_costs: (B, N) the winner's cost per horizon step (state cost after step k + input cost of step k,
            re-computed with the reference rollout in float32: sums to ``best_cost`` up to the kernel's
            round-off, NaN where it diverged; thesis Fig. 28) when ``SamplingMPC.record_step_costs`` is on,
            else NaN; +inf for a fallback robot.
        step_input_costs: (B, N) the input part of ``step_costs`` (always filled; +inf for a fallback robot).
        state_terms: (B, 9) the winner's state cost summed over the horizon, split by term (``cost.STATE_TERMS``
            order: z, vx, vy, vz, roll, pitch, roll, pitch and yaw rates; from the same reference rollout as
            ``step_costs``, so they add up to its state part) when ``record_step_costs`` is on, else NaN; +inf
            for a fallback robot.
        fallback: (B,) bool, True where an input (state, phase, base_xy_w, base_yaw, terrain_z_w, a
            reference) or the solution was not finite and the previous solution (or the first warm
            start if there was none) was returned unchanged. False always means a finite action.
        reason: "" or a sentence naming the fallback robots and why.
    """

    f: torch.Tensor
    d: torch.Tensor
    contact: torch.Tensor
    foot_target_w: torch.Tensor
    force_w: torch.Tensor
    p_h: torch.Tensor
    F_h: torch.Tensor
    best_cost: torch.Tensor
    best_input_cost: torch.Tensor
    initial_cost: torch.Tensor
    best_index: torch.Tensor
    warm_start_index: torch.Tensor
    best_encoded: torch.Tensor
    contact_horizon: torch.Tensor
    step_costs: torch.Tensor
    step_input_costs: torch.Tensor
    state_terms: torch.Tensor
    fallback: torch.Tensor
    reason: str = ""

    @property
    def best_state_cost(self) -> torch.Tensor:
        """(B,) state-only rollout cost of the chosen sample: sum_k (x_{k+1} - x_ref)^T Q (x_{k+1} - x_ref)."""
        finite = torch.isfinite(self.best_input_cost)  # a fallback robot: +inf, not inf - inf
        return torch.where(finite, self.best_cost - torch.where(finite, self.best_input_cost, 0.0), self.best_cost)


def check_tensor(name: str, value: object, shape: tuple[int, ...]) -> None:
    """Refuse anything but a tensor of exactly ``shape`` (one line naming ``name``, the shape wanted and given)."""
    if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape:
        raise ValueError(f"{name} must be a tensor of shape {shape}, got "
                         f"{tuple(getattr(value, 'shape', ())) or type(value).__name__}")


def check_phase(phase: torch.Tensor) -> None:
    """Refuse a finite phase outside the gait cycle (a non-finite one sends its robot to the fallback). 1.0 passes:
    the simulator's float64 phase just below 1 rounds to it in a float32 state."""
    outside = torch.isfinite(phase) & ((phase < 0.0) | (phase > 1.0))
    if bool(outside.any()):
        robots = torch.nonzero(outside.any(dim=1)).flatten().tolist()
        raise ValueError(f"phase must be in [0, 1) (the fraction of the gait cycle), got {phase[outside][:4].tolist()} "
                         f"for robots {robots[:10]}")


ACTION_FIELDS = ("f", "d", "foot_target_w", "force_w", "p_h", "F_h", "best_encoded")
"""The :class:`MPCResult` fields that make the action: all finite, or the robot falls back."""


def action_finite(result: MPCResult) -> torch.Tensor:
    """(B,) bool: every action field of the robot is finite."""
    b = result.f.shape[0]
    return torch.stack([torch.isfinite(getattr(result, n)).reshape(b, -1).all(dim=1) for n in ACTION_FIELDS]).all(0)


def describe_bad(bad_inputs: dict[str, torch.Tensor]) -> str:
    """'state of robots [1] is not finite (NaN/inf); refs.lin_vel_w of robots [0, 2] is not finite ...'."""
    parts = []
    for name, mask in bad_inputs.items():
        if bool(mask.any()):
            robots = torch.nonzero(mask).flatten().tolist()
            what = "the solution" if name == "solution" else name
            parts.append(f"{what} of robots {robots} is not finite (NaN/inf)")
    return "; ".join(parts)
