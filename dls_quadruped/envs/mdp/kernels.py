"""Reward kernels (thesis 4.3.1, Appendix D): SEK, SSEK, L2, L1 and the cost of transport.

All functions are batched over the leading dimension and return (B,).
"""

from __future__ import annotations

import torch


def sek(error: torch.Tensor, sigma: float) -> torch.Tensor:
    """Squared exponential kernel exp(-||e||^2 / (2 sigma^2)) in ]0, 1] (eq. 4.3.2 with its minus sign).

    Args:
        error: (B, D) or (B,) error x - x_ref.
        sigma: tracking width (same unit as the error).
    """
    sq = error.square() if error.dim() == 1 else error.square().sum(dim=-1)
    return torch.exp(-sq / (2.0 * sigma**2))


def dead_zone(x: torch.Tensor, alpha: torch.Tensor | float) -> torch.Tensor:
    """Piece-wise affine slack h(x) of Appendix D: 0 on [-alpha, alpha], x -+ alpha outside (slope 1).

    The thesis gives the plot, not the formula (eq. D.0.4 is missing); this is the continuous
    dead zone that plot shows: a plateau of full reward of half-width alpha around the reference.
    """
    return torch.sign(x) * torch.clamp(x.abs() - alpha, min=0.0)


def ssek_scalar(error: torch.Tensor, sigma: float, alpha: torch.Tensor | float) -> torch.Tensor:
    """Soft SEK of a scalar error: exp(-h(e)^2 / (2 sigma^2)), full reward while |e| <= alpha. (B,)"""
    return torch.exp(-dead_zone(error, alpha).square() / (2.0 * sigma**2))


def ssek_velocity(v_xy: torch.Tensor, v_ref_xy: torch.Tensor, sigma: float,
                  alpha: torch.Tensor | float, eps: float = 1e-6) -> torch.Tensor:
    """Soft squared exponential kernel (Appendix D): slack alpha along the command, stiff across it.

    e_par = ||v_ref|| - v_ref . v / ||v_ref||      (forward error, eq. D.0.3)
    e_perp = -(v_ref x v) / ||v_ref||              (lateral error, z of the 2-D cross product)
    r = exp(-(h(e_par)^2 + e_perp^2) / (2 sigma^2))  (eq. D.0.5)

    For a zero command there is no direction: every error is lateral (stiff), r = SEK(v).

    Args:
        v_xy: (B, 2) measured velocity; v_ref_xy: (B, 2) command; sigma: width; alpha: (B,) or float slack.
    """
    norm = torch.linalg.vector_norm(v_ref_xy, dim=-1)
    safe = norm.clamp_min(eps)
    dot = (v_ref_xy * v_xy).sum(dim=-1)
    cross = v_ref_xy[:, 0] * v_xy[:, 1] - v_ref_xy[:, 1] * v_xy[:, 0]
    moving = norm > eps
    e_par = torch.where(moving, norm - dot / safe, torch.zeros_like(norm))
    e_perp = torch.where(moving, -cross / safe, torch.linalg.vector_norm(v_xy, dim=-1))
    return torch.exp(-(dead_zone(e_par, alpha).square() + e_perp.square()) / (2.0 * sigma**2))


def l2(error: torch.Tensor) -> torch.Tensor:
    """Quadratic penalty ||e||^2 (eq. 4.3.4), (B,); a (B,) input is squared element-wise."""
    return error.square() if error.dim() == 1 else error.square().sum(dim=-1)


def l1(error: torch.Tensor) -> torch.Tensor:
    """Linear penalty ||e||_1 (eq. 4.3.5 as a norm, so it is >= 0), (B,)."""
    return error.abs() if error.dim() == 1 else error.abs().sum(dim=-1)


def cost_of_transport(torque: torch.Tensor, joint_vel: torch.Tensor, speed: torch.Tensor, weight: float,
                      alpha: float = 0.3, min_speed: float = 0.1) -> torch.Tensor:
    """Cost of transport, eq. 4.3.7 (Yang et al. 2021): sum_j max(tau_j qdot_j + alpha tau_j^2, 0) / (m g v).

    alpha tau^2 models the motor's Joule heating (stall power), the max(., 0) forbids regenerating
    energy. The speed is floored at ``min_speed`` so standing still does not divide by zero.

    Args:
        torque: (B, J) [N m]; joint_vel: (B, J) [rad/s]; speed: (B,) [m/s] base speed;
        weight: m g [N]; alpha: [W / (N m)^2]; min_speed: [m/s].

    Returns:
        (B,) dimensionless CoT >= 0.
    """
    return motor_power(torque, joint_vel, alpha) / (weight * speed.clamp_min(min_speed))


def motor_power(torque: torch.Tensor, joint_vel: torch.Tensor, alpha: float = 0.3) -> torch.Tensor:
    """(B,) [W] the numerator of eq. 4.3.7: sum_j max(tau_j qdot_j + alpha tau_j^2, 0)."""
    return torch.clamp(torque * joint_vel + alpha * torque.square(), min=0.0).sum(dim=-1)
