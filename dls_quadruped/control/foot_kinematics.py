"""Batched foot kinematics in torch on any device: foot centres, velocities, Jacobians and ``Jdot qdot``.

From MuJoCo's free-joint state (``qpos`` (B, 19), ``qvel`` (B, 18)) and the chain parameters of
``control/leg_chain.py``, in the state's dtype and device, with no Python loop over robots; used by
``control/torch_dynamics.py``'s ``TorchLegDynamics``.

Algorithm
---------
Batched over (B, 4 legs), vectors only. Joint k turns body k by ``q_k - qpos0_k`` about its axis through
its anchor; in the parent's frame a point x of body k lies at ``A_k + Rp_k Rot(axis_k, q_k - qpos0_k)
(x - jp_k)`` (``A_k = t_k + Rp_k jp_k``: body offset t, orientation Rp, joint anchor jp in body k).
Positions: the foot, then the anchors ``a_k`` and axes ``z_k`` of the deeper joints, are carried from
the foot inwards to the base frame with Rodrigues' formula on vectors (no rotation matrices are
composed), then to the world with one batched product by the base rotation. Velocities and
accelerations at ``qacc = 0``: an outward recursion along each chain from the base origin through the
anchors to the foot with the rigid-body point rules ``v = v_ref + omega x d``,
``acc = acc_ref + alpha x d + omega x (omega x d)`` (d from the previous reference point, which is
fixed in the same body), and the body rates ``omega_k = omega_{k-1} + qd_k z_k``,
``alpha_k = alpha_{k-1} + qd_k (omega_{k-1} x z_k)`` (the axis turns with body k-1; ``qdd = 0``),
starting from ``v_w``, ``omega_w = R omega_b`` and zero accelerations. The leg Jacobian columns are
``z_k x (p_foot - a_k)``; the base columns (``J_base``, for MuJoCo's ``qvel[0:6]``) are
``[I_3, -[p_foot - p_base]x R]``. Everything is analytic (no finite differences) and elementwise over
robots, so a robot with a non-finite state spoils only its own rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dls_quadruped.control.leg_chain import LegChainParams
from dls_quadruped.robots.aliengo import constants as C


@dataclass
class FootKinematics:
    """Foot-centre kinematics of B robots (torch, the state's device and dtype; legs FL, FR, RL, RR).

    Attributes:
        foot_pos_w: (B, 4, 3) [m] foot centres, world frame.
        foot_vel_w: (B, 4, 3) [m/s] foot-centre velocities (full Jacobian times qvel), world frame.
        J_leg: (B, 4, 3, 3) [m] world-aligned Jacobian w.r.t. the leg's own joint rates (hip, thigh, calf).
        J_base: (B, 4, 3, 6) world-aligned Jacobian w.r.t. MuJoCo's base velocities ``qvel[0:6]``
            (v_w, then omega_b in the base frame).
        Jdot_qdot: (B, 4, 3) [m/s^2] foot-centre acceleration at MuJoCo's ``qacc = 0``.
    """

    foot_pos_w: torch.Tensor
    foot_vel_w: torch.Tensor
    J_leg: torch.Tensor
    J_base: torch.Tensor
    Jdot_qdot: torch.Tensor


def quat_wxyz_to_matrix(quat: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternions (w, x, y, z), any norm -> (..., 3, 3) rotation matrices."""
    w, x, y, z = (quat / quat.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack([
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    ], dim=-1).unflatten(-1, (3, 3))


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a x b over the last axis (broadcasting)."""
    return torch.linalg.cross(a, b, dim=-1)


class ChainTensors:
    """The chain parameters of one :class:`LegChainParams` as tensors of one device and dtype.

    Per joint k, in the frame of its parent (the base for k = 0): the anchor ``A_k = t_k + Rp_k jp_k`` and
    axis ``Rp_k axis_k``; a point x of body k is at ``A_k + Rp_k Rot(axis_k, q_k - qpos0_k) (x - jp_k)``.
    """

    def __init__(self, p: LegChainParams, device: torch.device, dtype: torch.dtype):
        def t(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(a, dtype=dtype, device=device)

        anchor_parent = p.body_pos + np.einsum("lkij,lkj->lki", p.body_rot, p.anchor)  # (4, 3, 3)
        axis_parent = np.einsum("lkij,lkj->lki", p.body_rot, p.axis)
        self.axis = t(p.axis[:, None])  # (4, 1, 3 joints, 3): broadcasts over (B, 4, n, 3)
        self.body_rot = t(p.body_rot)  # (4, 3, 3, 3)
        self.rotated = [bool(np.any(p.body_rot[:, k] != np.eye(3))) for k in range(3)]
        self.jp = t(p.anchor)  # (4, 3, 3) joint anchors in their own body's frame
        self.anchor_parent, self.axis_parent = t(anchor_parent), t(axis_parent)
        self.foot_local = t(p.foot - p.anchor[:, 2])  # (4, 3) foot relative to the calf anchor, calf frame
        self.qpos0 = t(p.qpos0)
        self.has_qpos0 = bool(np.any(p.qpos0 != 0.0))
        self.leg_qpos = torch.as_tensor(p.qpos_adr.reshape(-1), device=device)
        self.leg_dof = torch.as_tensor(p.dof_adr.reshape(-1), device=device)


def _joint_to_parent(pt: ChainTensors, k: int, s: torch.Tensor, c: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``Rp_k Rot(axis_k, q_k) y`` for vectors y (B, 4, n, 3) of body k's frame (Rodrigues on vectors).

    s, c: (B, 4) sine and cosine of ``q_k - qpos0_k``.
    """
    a = pt.axis[:, :, k]  # (4, 1, 3)
    ay = _cross(a.expand_as(y), y)
    aay = _cross(a.expand_as(y), ay)
    y = y + s[:, :, None, None] * ay + (1.0 - c)[:, :, None, None] * aay
    if pt.rotated[k]:
        R = pt.body_rot[:, k, None]  # (4, 1, 3, 3)
        y = R[..., 0] * y[..., 0:1] + R[..., 1] * y[..., 1:2] + R[..., 2] * y[..., 2:3]
    return y


def foot_kinematics(qpos: torch.Tensor, qvel: torch.Tensor, pt: ChainTensors) -> FootKinematics:
    """Foot kinematics from MuJoCo states (module doc "Algorithm"); see :meth:`TorchLegDynamics.kinematics`."""
    B, n = qpos.shape[0], C.NUM_LEGS
    R_b = quat_wxyz_to_matrix(qpos[:, 3:7])  # (B, 3, 3) base -> world
    p_b = qpos[:, 0:3]
    q = qpos[:, pt.leg_qpos].view(B, n, 3)
    qd = qvel[:, pt.leg_dof].view(B, n, 3)
    if pt.has_qpos0:
        q = q - pt.qpos0
    s, c = torch.sin(q), torch.cos(q)

    # Positions: the foot, the anchors and axes of the deeper joints, carried from the foot inwards to the base
    # frame, vectors only. Stack rows: [foot, anchor_2, anchor_1 | axis_2, axis_1] as they appear.
    foot = pt.foot_local.expand(B, n, 3).unsqueeze(2)  # (B, 4, 1, 3), relative to the calf anchor
    pts = _joint_to_parent(pt, 2, s[..., 2], c[..., 2], foot) + pt.anchor_parent[:, 2, None]  # body-1 frame
    pts = torch.cat([pts, pt.anchor_parent[:, 2, None].expand(B, n, 1, 3)], dim=2)  # [foot, anchor_2]
    dirs = pt.axis_parent[:, 2, None].expand(B, n, 1, 3)  # [axis_2]
    y = torch.cat([pts - pt.jp[:, 1, None], dirs], dim=2)
    y = _joint_to_parent(pt, 1, s[..., 1], c[..., 1], y)  # body-0 frame
    pts = torch.cat([y[:, :, 0:2] + pt.anchor_parent[:, 1, None], pt.anchor_parent[:, 1, None].expand(B, n, 1, 3)],
                    dim=2)  # [foot, anchor_2, anchor_1]
    dirs = torch.cat([y[:, :, 2:3], pt.axis_parent[:, 1, None].expand(B, n, 1, 3)], dim=2)  # [axis_2, axis_1]
    y = torch.cat([pts - pt.jp[:, 0, None], dirs], dim=2)
    y = _joint_to_parent(pt, 0, s[..., 0], c[..., 0], y)  # base frame
    y = torch.cat([y[:, :, 0:3] + pt.anchor_parent[:, 0, None], pt.anchor_parent[:, 0, None].expand(B, n, 1, 3),
                   y[:, :, 3:5], pt.axis_parent[:, 0, None].expand(B, n, 1, 3)], dim=2)
    # rows: foot, anchor_2, anchor_1, anchor_0 (relative to the base origin), axis_2, axis_1, axis_0 -> world
    w = (y.reshape(B, n * 7, 3) @ R_b.transpose(1, 2)).view(B, n, 7, 3)
    p_f = w[:, :, 0] + p_b.unsqueeze(1)
    r_f = w[:, :, 0]  # foot relative to the base origin, world-aligned
    anchors = w[:, :, 1:4].flip(2)  # (B, 4, 3 joints, 3) relative to the base origin
    axes = w[:, :, 4:7].flip(2)

    # Velocities and accelerations at qacc = 0 along the chain (reference point: base origin, then each anchor).
    ref = torch.zeros_like(r_f)
    v_ref = qvel[:, None, 0:3].expand(B, n, 3)
    acc_ref = torch.zeros_like(r_f)
    omega = (R_b @ qvel[:, 3:6, None]).view(B, 1, 3).expand(B, n, 3)
    alpha = torch.zeros_like(r_f)
    for k in range(4):
        point = anchors[:, :, k] if k < 3 else r_f
        d = point - ref
        w_d = _cross(omega, d)
        v_ref = v_ref + w_d
        acc_ref = acc_ref + _cross(alpha, d) + _cross(omega, w_d)
        if k < 3:
            z = axes[:, :, k]
            alpha = alpha + qd[:, :, k, None] * _cross(omega, z)
            omega = omega + qd[:, :, k, None] * z
            ref = point
    J_leg = _cross(axes, r_f.unsqueeze(2) - anchors).transpose(-1, -2)  # columns z_k x (p_f - a_k)
    # d v_f / d omega_b: omega_w x r = (R_b omega_b) x r, column j = R_b[:, j] x r
    J_ang = _cross(R_b.transpose(1, 2).unsqueeze(1), r_f.unsqueeze(2)).transpose(-1, -2)
    eye = torch.eye(3, dtype=qpos.dtype, device=qpos.device).expand(B, n, 3, 3)
    return FootKinematics(foot_pos_w=p_f, foot_vel_w=v_ref, J_leg=J_leg, J_base=torch.cat([eye, J_ang], dim=-1),
                          Jdot_qdot=acc_ref)
