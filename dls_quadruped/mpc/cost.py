"""Quadratic MPC cost (thesis eq. 3.2.1, Tables 9 and 10) and its references.

J = sum_{k=0}^{N-1} (x_{k+1} - x_ref)^T Q (x_{k+1} - x_ref) + (u_k - u_ref)^T R (u_k - u_ref)

The sampler minimises J. Evaluations compare controllers by its *state* part alone (the thesis's own
evaluation code leaves the input terms out): the input part is the foothold deviation from the
heuristic reference, zero by construction for a naive warm start whose footholds are that heuristic,
so J would favour it over any other warm start whatever the states it reaches.

The state after each input is costed (x_0 is the same for every sample, so Algorithm 2's
J(x_i, u_i) indexing only adds a constant); the "initial cost" is the state cost of x_0.
A NaN cost counts as +inf (MuJoCo MPC convention) so a diverged sample never wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dls_quadruped.core.torch_cache import constant_tensor
from dls_quadruped.mpc.config import CostWeights
from dls_quadruped.mpc.srbd import NUM_LEGS, SRBDModel, rollout_reference


@dataclass
class Refs:
    """Cost references of B robots.

    Attributes:
        com_height_w: (B,) [m] desired CoM height, world z.
        lin_vel_w: (B, 2) [m/s] commanded CoM velocity (v_x, v_y), world frame (v_z ref = 0).
        yaw_rate: (B,) [rad/s] commanded yaw rate (reference of omega_b,z; roll/pitch rates ref 0).
        foothold_w: (B, 4, 3) [m] reference footholds (e.g. heuristic, eq. 2.2.4), world.
    Roll and pitch references are 0 (flat attitude); x, y, yaw and the feet are not costed.
    """

    com_height_w: torch.Tensor
    lin_vel_w: torch.Tensor
    yaw_rate: torch.Tensor
    foothold_w: torch.Tensor

    def validate(self, batch: int) -> None:
        """Raise ValueError naming the field whose shape is not as documented."""
        expected = {"com_height_w": (batch,), "lin_vel_w": (batch, 2), "yaw_rate": (batch,),
                    "foothold_w": (batch, NUM_LEGS, 3)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape:
                raise ValueError(f"Refs.{name} must have shape {shape} (B = {batch}), got "
                                 f"{tuple(getattr(value, 'shape', ()))}")

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> Refs:
        """Copy on another device/dtype."""
        return Refs(*(t.to(device=device, dtype=dtype) for t in (self.com_height_w, self.lin_vel_w, self.yaw_rate,
                                                                   self.foothold_w)))

    def state_vector(self) -> torch.Tensor:
        """(B, 24) x_ref = [0, 0, h, vx, vy, 0, 0, 0, 0, 0, 0, yaw_rate, 0 x 12]."""
        z = torch.zeros_like(self.com_height_w)
        cols = [z, z, self.com_height_w, self.lin_vel_w[:, 0], self.lin_vel_w[:, 1], z, z, z, z, z, z, self.yaw_rate]
        return torch.cat([torch.stack(cols, dim=-1), torch.zeros_like(self.foothold_w).flatten(-2)], dim=-1)

    def input_vector(self) -> torch.Tensor:
        """(B, 24) u_ref = [reference footholds (4 x 3), forces 0 (4 x 3)]."""
        return torch.cat([self.foothold_w.flatten(-2), torch.zeros_like(self.foothold_w).flatten(-2)], dim=-1)


def _diag(values: tuple[float, ...], like: torch.Tensor) -> torch.Tensor:
    return constant_tensor(tuple(values), like.dtype, like.device)


def state_cost(x: torch.Tensor, x_ref: torch.Tensor, weights: CostWeights) -> torch.Tensor:
    """(x - x_ref)^T Q (x - x_ref) with diagonal Q; x: (..., 24), x_ref broadcastable. Returns (...)."""
    return ((x - x_ref) ** 2 * _diag(weights.q_diag(), x)).sum(-1)


STATE_TERMS = {"z": 2, "vx": 3, "vy": 4, "vz": 5, "roll": 6, "pitch": 7, "roll_rate": 9, "pitch_rate": 10,
               "yaw_rate": 11}
"""Costed state entries (Table 9) by name -> index in x; every other entry has weight 0."""


def state_cost_terms(x: torch.Tensor, x_ref: torch.Tensor, weights: CostWeights) -> torch.Tensor:
    """(..., 9) the state cost split by term, in ``STATE_TERMS`` order: Q_ii (x_i - x_ref,i)^2; sums to
    :func:`state_cost`. Which part of a cost is height, sway or roll (e.g. Table 14's discussion)."""
    idx = list(STATE_TERMS.values())
    q = _diag(weights.q_diag(), x)[idx]
    return (x[..., idx] - x_ref[..., idx]) ** 2 * q


def input_cost(u: torch.Tensor, u_ref: torch.Tensor, weights: CostWeights) -> torch.Tensor:
    """(u - u_ref)^T R (u - u_ref) with diagonal R; u = [p_td (12), F (12)]: (..., 24). Returns (...)."""
    return ((u - u_ref) ** 2 * _diag(weights.r_diag(), u)).sum(-1)


def nan_to_inf(cost: torch.Tensor) -> torch.Tensor:
    """Replace NaN costs by +inf (a diverged rollout must never be the argmin)."""
    return torch.where(torch.isnan(cost), torch.full_like(cost, float("inf")), cost)


def initial_cost(x0: torch.Tensor, refs: Refs, weights: CostWeights) -> torch.Tensor:
    """Thesis 7.3.1 "initial cost": the state cost of the current state. x0: (B, 24); returns (B,)."""
    return nan_to_inf(state_cost(x0, refs.state_vector(), weights))


def rollout_cost_reference(
    x0: torch.Tensor, contact: torch.Tensor, foot_target_w: torch.Tensor, force_w: torch.Tensor,
    refs: Refs, model: SRBDModel, weights: CostWeights, dt: float,
) -> torch.Tensor:
    """Cost of each sample's rollout, plain eager torch (the in-run reference kernel).

    Args:
        x0: (B, 24); contact: (B, M, N, 4); foot_target_w, force_w: (B, M, N, 4, 3) world.

    Returns:
        (B, M) total cost, NaN replaced by +inf.
    """
    return nan_to_inf(rollout_step_costs(x0, contact, foot_target_w, force_w, refs, model, weights, dt).sum(-1))


def input_step_costs(foot_target_w: torch.Tensor, force_w: torch.Tensor, refs: Refs,
                     weights: CostWeights) -> torch.Tensor:
    """(B, M, N) input cost (u_k - u_ref)^T R (u_k - u_ref) of each horizon step; foot_target_w, force_w:
    (B, M, N, 4, 3) world. With Tables 9-10's R this is the foothold-deviation term alone (R = 1000 on
    the touch-down x, y; 0 on the forces): zero for footholds at the reference (the naive warm start's
    heuristic ones), so it is the part of the rollout cost that a comparison across warm starts leaves out."""
    u = torch.cat([foot_target_w.flatten(-2), force_w.flatten(-2)], dim=-1)  # (B, M, N, 24)
    return input_cost(u, refs.input_vector()[:, None, None, :], weights)


def rollout_step_costs(
    x0: torch.Tensor, contact: torch.Tensor, foot_target_w: torch.Tensor, force_w: torch.Tensor,
    refs: Refs, model: SRBDModel, weights: CostWeights, dt: float,
) -> torch.Tensor:
    """(B, M, N) cost of each horizon step k: state cost of x_{k+1} plus input cost of u_k (thesis Fig. 28).
    NaN where the rollout diverged. Arguments as :func:`rollout_cost_reference`."""
    return rollout_step_costs_and_terms(x0, contact, foot_target_w, force_w, refs, model, weights, dt)[0]


def rollout_step_costs_and_terms(
    x0: torch.Tensor, contact: torch.Tensor, foot_target_w: torch.Tensor, force_w: torch.Tensor,
    refs: Refs, model: SRBDModel, weights: CostWeights, dt: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(:func:`rollout_step_costs` (B, M, N), (B, M, 9) the state part summed over the horizon and split by term
    in ``STATE_TERMS`` order) from one reference rollout: which terms a rollout's cost is made of."""
    traj = rollout_reference(x0, contact, foot_target_w, force_w, model, dt)  # (B, M, N+1, 24)
    x_ref = refs.state_vector()[:, None, None, :]
    u = torch.cat([foot_target_w.flatten(-2), force_w.flatten(-2)], dim=-1)  # (B, M, N, 24)
    u_ref = refs.input_vector()[:, None, None, :]
    step = state_cost(traj[:, :, 1:], x_ref, weights) + input_cost(u, u_ref, weights)
    return step, state_cost_terms(traj[:, :, 1:], x_ref, weights).sum(-2)
