"""Heuristic latent-action producer: a virtual-model balance controller (baseline and test fixture).

It is *not* part of the low-level controller: it plays the role the policy or the MPC
plays in the full system, closing the loop on base height, attitude and velocity by
producing latent actions (f, d, p_h, F_h):

* gait: fixed periodic trot (f, d) or standing (d = 1, all legs in stance);
* footholds: under the hip plus a velocity term (eq. 2.2.4, frame H)::

      p_h = T_stance / 2 * v_cmd + sqrt(z / g) (v - v_cmd)

* forces: a PD law on height, attitude and velocity gives a desired body wrench
  ``w = (F, tau)`` (world frame), distributed over the stance legs by regularised least
  squares around the equal-share prior ``F_i = (0, 0, m g / n_stance)``::

      F = F_prior + (A^T S A + alpha I)^-1 A^T S (w - A F_prior),   A = [I ...; [r_i]x ...] (stance columns)

  with S a diagonal weight favouring the torque rows (see ``BalanceConfig.wrench_weights``).

Everything is batched over robots; angles come from the base quaternion.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dls_quadruped.control.latent_action import LatentAction
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.core.state import RobotState
from dls_quadruped.robots.aliengo import constants as C


@dataclass(frozen=True)
class BalanceConfig:
    """Gains of the virtual-model balance controller.

    Attributes:
        height: desired base height above the mean stance-foot ground level [m].
        kp_z, kd_z: height PD [1/s^2, 1/s] (scaled by the mass).
        kp_att, kd_att: roll/pitch PD [1/s^2, 1/s] scaled by ``inertia``; kd_att also damps yaw rate.
        inertia: approximate whole-body principal inertia (roll, pitch, yaw) [kg m^2] at the home pose.
        kd_vel: horizontal velocity gain [1/s] (scaled by the mass).
        kp_xy: pull of the base towards the centroid of the feet [1/s^2] (scaled by the mass).
        freq, duty: trot gait parameters; ``stand=True`` in the call overrides to d = 1.
        alpha: regularisation of the force distribution (pull towards the equal-share prior).
        wrench_weights: squared weights of (F_x, F_y, F_z, tau_x, tau_y, tau_z) errors in the distribution.
    """

    height: float = 0.34
    kp_z: float = 400.0
    kd_z: float = 40.0
    kp_att: float = 150.0
    kd_att: float = 15.0
    inertia: tuple[float, float, float] = (0.22, 0.89, 0.92)
    kd_vel: float = 4.0
    kp_xy: float = 20.0
    freq: float = 1.5
    duty: float = 0.6
    alpha: float = 1e-3
    wrench_weights: tuple[float, ...] = (1.0, 1.0, 10.0, 100.0, 100.0, 100.0)


def _skew(v: torch.Tensor) -> torch.Tensor:
    """[v]x for (..., 3) -> (..., 3, 3)."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*v.shape, 3)


class BalanceController:
    """Batched virtual-model balance controller producing latent actions."""

    def __init__(self, cfg: BalanceConfig = BalanceConfig(), mass: float = C.TOTAL_MASS, gravity: float = C.GRAVITY):
        self.cfg = cfg
        self.mass = mass
        self.gravity = gravity

    def __call__(self, state: RobotState, cmd_vel_h: torch.Tensor, stand: bool = False) -> LatentAction:
        """Latent action for every robot (physical units, frame H; clip it with ``latent_action.clip``).

        Args:
            state: current robot state (B robots).
            cmd_vel_h: (B, 3) commanded (v_x, v_y) [m/s] in frame H and yaw rate [rad/s].
            stand: all legs in stance (d = 1, f = 0) instead of the trot.
        """
        cfg = self.cfg
        dtype = torch.float64
        B = state.base_pos_w.shape[0]
        R = quat_to_rotmat(state.base_quat_w.to(dtype))
        rpy = rpy_from_rotmat(R)
        yaw = rpy[:, 2]
        cy, sy = torch.cos(yaw), torch.sin(yaw)
        v_w = state.base_lin_vel_w.to(dtype)
        w_w = (R @ state.base_ang_vel_b.to(dtype).unsqueeze(-1)).squeeze(-1)
        cmd = cmd_vel_h.to(dtype)
        v_cmd_w = torch.stack([cy * cmd[:, 0] - sy * cmd[:, 1], sy * cmd[:, 0] + cy * cmd[:, 1]], dim=-1)

        if stand:
            f = torch.zeros(B, 4, dtype=dtype)
            d = torch.ones(B, 4, dtype=dtype)
            stance = torch.ones(B, 4, dtype=torch.bool)
        else:
            f = torch.full((B, 4), cfg.freq, dtype=dtype)
            d = torch.full((B, 4), cfg.duty, dtype=dtype)
            stance = state.phase.to(dtype) < d
        n_stance = stance.sum(dim=1).clamp_min(1).to(dtype)

        # --- desired wrench on the body (world frame) ---
        foot_w = state.foot_pos_w.to(dtype)
        ground_z = (
            torch.where(stance, foot_w[..., 2], 0.0).sum(dim=1) / n_stance - C.FOOT_RADIUS
        )  # mean stance-foot ground level [m]
        z = state.base_pos_w[:, 2].to(dtype) - ground_z
        m, g = self.mass, self.gravity
        # horizontal anchor: the base is pulled over the centroid of all four feet (no drift when standing)
        anchor = foot_w[..., :2].mean(dim=1) - state.base_pos_w[:, :2].to(dtype)
        force = torch.stack(
            [
                m * (cfg.kd_vel * (v_cmd_w[:, 0] - v_w[:, 0]) + cfg.kp_xy * anchor[:, 0]),
                m * (cfg.kd_vel * (v_cmd_w[:, 1] - v_w[:, 1]) + cfg.kp_xy * anchor[:, 1]),
                m * (g + cfg.kp_z * (cfg.height - z) - cfg.kd_z * v_w[:, 2]),
            ],
            dim=-1,
        )
        inertia = torch.tensor(cfg.inertia, dtype=dtype)
        # roll and pitch are rotations about the yaw-aligned axes of frame H: build the PD torque
        # there and rotate it to the world (a world-axis law reverses sign at yaw = pi)
        w_h = torch.stack([cy * w_w[:, 0] + sy * w_w[:, 1], -sy * w_w[:, 0] + cy * w_w[:, 1], w_w[:, 2]], dim=-1)
        torque_h = inertia * torch.stack(
            [
                -cfg.kp_att * rpy[:, 0] - cfg.kd_att * w_h[:, 0],
                -cfg.kp_att * rpy[:, 1] - cfg.kd_att * w_h[:, 1],
                cfg.kd_att * (cmd[:, 2] - w_h[:, 2]),
            ],
            dim=-1,
        )
        torque = torch.stack(
            [cy * torque_h[:, 0] - sy * torque_h[:, 1], sy * torque_h[:, 0] + cy * torque_h[:, 1], torque_h[:, 2]],
            dim=-1,
        )
        wrench = torch.cat([force, torque], dim=-1)  # (B, 6)

        # --- distribute over stance legs ---
        r = foot_w - state.base_pos_w.to(dtype).unsqueeze(1)  # (B, 4, 3) moment arms
        eye = torch.eye(3, dtype=dtype).expand(B, 4, 3, 3)
        A = torch.cat([eye, _skew(r)], dim=-2)  # (B, 4, 6, 3)
        A = (A * stance[..., None, None]).permute(0, 2, 1, 3).reshape(B, 6, 12)
        prior = torch.zeros(B, 4, 3, dtype=dtype)
        prior[..., 2] = torch.where(stance, (m * g / n_stance).unsqueeze(1), m * g / 4)
        prior = prior.reshape(B, 12)
        resid = wrench - (A @ prior.unsqueeze(-1)).squeeze(-1)
        # weighted least squares: with two stance legs the torque about the support line is only
        # reachable through horizontal forces, so torque errors must outweigh horizontal-force errors
        S2 = torch.tensor(cfg.wrench_weights, dtype=dtype)  # (6,)
        AtS2 = A.transpose(1, 2) * S2  # (B, 12, 6)
        normal = AtS2 @ A + cfg.alpha * torch.eye(12, dtype=dtype)
        F_w = prior + torch.linalg.solve(normal, (AtS2 @ resid.unsqueeze(-1))).squeeze(-1)
        F_w = F_w.reshape(B, 4, 3)
        F_w = torch.where(stance.unsqueeze(-1), F_w, prior.reshape(B, 4, 3))
        F_h = torch.stack([cy[:, None] * F_w[..., 0] + sy[:, None] * F_w[..., 1],
                           -sy[:, None] * F_w[..., 0] + cy[:, None] * F_w[..., 1], F_w[..., 2]], dim=-1)

        # --- footholds (eq. 2.2.4 in frame H, relative to the nominal foothold) ---
        v_h = torch.stack([cy * v_w[:, 0] + sy * v_w[:, 1], -sy * v_w[:, 0] + cy * v_w[:, 1]], dim=-1)
        t_stance = (d / f.clamp_min(1e-6)).clamp(max=1.0)  # (B, 4) [s]
        k_fb = (cfg.height / g) ** 0.5
        p_h = t_stance.unsqueeze(-1) / 2 * cmd[:, None, :2] + k_fb * (v_h - cmd[:, :2]).unsqueeze(1)
        if stand:
            p_h = torch.zeros_like(p_h)
        return LatentAction(f, d, p_h, F_h)
