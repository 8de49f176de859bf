"""Swing trajectory generator: two cubic Bézier segments (thesis 2.2.4, Appendix B).

The foot goes from the lift-off point ``p_lo`` up to an apex and down to the touch-down
target ``p_td``. The swing lasts ``T_s = (1 - d) / f`` seconds; the ascent covers the first
half (swing progress ``s < 0.5``) and the descent the second half, each lasting
``T_seg = T_s / 2``. Inside a segment the Bézier parameter is ``tau = 2 s`` (ascent) or
``tau = 2 s - 1`` (descent), so ``dtau/dt = 1 / T_seg`` and the derivatives returned here are
true time derivatives in m/s and m/s^2, ready for the swing feedback-linearisation law.

Control points (D = p_td.xy - p_lo.xy, m_xy = midpoint, z_apex = max(z_lo, z_td) + h):

    ascent  a0 = p_lo
            a1 = p_lo                           -> zero velocity at lift-off
            a2 = (p_lo.xy + D/4, z_apex)        -> zero vertical velocity at the apex
            a3 = (m_xy,          z_apex)        -> apex
    descent b0 = (m_xy,          z_apex)
            b1 = (p_lo.xy + 3D/4, z_apex)       -> b1 - b0 = a3 - a2: C1 at the apex
            b2 = p_td
            b3 = p_td                           -> zero velocity at touch-down

The horizontal control points (0, 0, D/4, D/2 | D/2, 3D/4, D, D) are exactly the de Casteljau
split at s = 1/2 of the single cubic with points (0, 0, D, D), so the horizontal motion is the
smooth ease ``xy(s) = p_lo.xy + D (3 s^2 - 2 s^3)`` over the whole swing (continuous in
position, velocity and acceleration). Vertically each segment is a smooth step between
its end heights with zero slope at both ends; the vertical acceleration jumps at the apex
unless z_lo = z_td, which a cubic per segment with these boundary conditions cannot avoid.

Moving target. The touch-down target is re-planned while the foot swings (it is expressed relative to
the moving base), so ``p_td`` is a function of time. With ``target_vel_w`` = dp_td/dt the returned
velocity and acceleration are the total time derivatives of the same curve,

    vel = dpos/ds s' + (dpos/dp_td) v_td,   acc = d2pos/ds2 s'^2 + 2 (d2pos/ds dp_td) v_td s'

(the target's own acceleration neglected), with dpos_xy/dp_td_xy = 3 s^2 - 2 s^3 over the whole swing and
dz/dz_td = 3 tau^2 - 2 tau^3 inside a segment whose end height z_td sets (1 on the descent when the apex
follows z_td). Without it the reference is fed forward as if the target stood still, and a foot tracking it
trails a target that moves with the body. At lift-off the extra terms vanish; at
touch-down the reference velocity is the target's velocity.

All functions are pure torch, batched over any leading dimensions, and keep the dtype and
device of their inputs.
"""

from __future__ import annotations

import torch

MIN_SWING_DURATION = 1e-3
"""Lower clamp on T_s [s]: keeps the 1/T_seg and 1/T_seg^2 time scaling finite when f -> inf or d -> 1."""


def cubic_bezier(
    cp0: torch.Tensor, cp1: torch.Tensor, cp2: torch.Tensor, cp3: torch.Tensor, t: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Cubic Bézier curve and its parameter derivatives (thesis eq. B.1.1).

    Args:
        cp0, cp1, cp2, cp3: control points, any shape (..., D); mutually broadcastable.
        t: curve parameter in [0, 1] (not clamped here), broadcastable against the control
            points (pass (..., 1) for points of shape (..., D)).

    Returns:
        B: the point; dB: dB/dt; ddB: d2B/dt2 (derivatives w.r.t. the parameter t, not time).
    """
    u = 1.0 - t
    # B(t) = cp0 u^3 + 3 cp1 t u^2 + 3 cp2 t^2 u + cp3 t^3
    b = cp0 * u**3 + 3.0 * cp1 * t * u**2 + 3.0 * cp2 * t**2 * u + cp3 * t**3
    # B'(t) = 3 [(cp1 - cp0) u^2 + 2 (cp2 - cp1) t u + (cp3 - cp2) t^2]
    db = 3.0 * ((cp1 - cp0) * u**2 + 2.0 * (cp2 - cp1) * t * u + (cp3 - cp2) * t**2)
    # B''(t) = 6 [(cp2 - 2 cp1 + cp0) u + (cp3 - 2 cp2 + cp1) t]
    ddb = 6.0 * ((cp2 - 2.0 * cp1 + cp0) * u + (cp3 - 2.0 * cp2 + cp1) * t)
    return b, db, ddb


def swing_reference(
    p_lo_w: torch.Tensor,
    p_td_w: torch.Tensor,
    step_height: torch.Tensor | float,
    progress: torch.Tensor,
    swing_duration: torch.Tensor | float,
    target_vel_w: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Foot position, velocity and acceleration along the swing (control points: module doc).

    Args:
        p_lo_w: (..., 3) [m] lift-off foot position, world frame.
        p_td_w: (..., 3) [m] touch-down target, world frame.
        step_height: (...) or scalar [m] apex clearance above max(z_lo, z_td).
        progress: (...) swing progress s (see :func:`gait.swing_progress`); clamped to [0, 1].
        swing_duration: (...) or scalar [s] whole swing duration T_s = (1 - d) / f; clamped
            below at :data:`MIN_SWING_DURATION`.
        target_vel_w: (..., 3) [m/s] velocity of the touch-down target, world frame, or None for a
            target at rest (module doc: moving target).

    Returns:
        pos (..., 3) [m], vel (..., 3) [m/s], acc (..., 3) [m/s^2], world frame, time units.
    """
    ref = p_lo_w
    s = torch.as_tensor(progress, dtype=ref.dtype, device=ref.device).clamp(0.0, 1.0).unsqueeze(-1)
    # a Python number stays one: a tensor built from it per call is a host-to-device copy on a GPU
    h = step_height.to(ref) if isinstance(step_height, torch.Tensor) else float(step_height)
    t_s = torch.as_tensor(swing_duration, dtype=ref.dtype, device=ref.device).clamp_min(MIN_SWING_DURATION)
    t_seg = (0.5 * t_s).unsqueeze(-1) if t_s.dim() > 0 else 0.5 * t_s  # (..., 1) or scalar [s]

    delta_xy = p_td_w[..., :2] - p_lo_w[..., :2]  # D
    z_apex = torch.maximum(p_lo_w[..., 2], p_td_w[..., 2]) + h  # (...)
    apex = torch.cat([p_lo_w[..., :2] + 0.5 * delta_xy, z_apex.unsqueeze(-1)], dim=-1)
    pre_apex = torch.cat([p_lo_w[..., :2] + 0.25 * delta_xy, z_apex.unsqueeze(-1)], dim=-1)
    post_apex = torch.cat([p_lo_w[..., :2] + 0.75 * delta_xy, z_apex.unsqueeze(-1)], dim=-1)

    # Evaluate only the active segment: select its control points, then one Bézier call.
    ascent = s < 0.5  # (..., 1)
    cp0 = torch.where(ascent, p_lo_w, apex)
    cp1 = torch.where(ascent, p_lo_w, post_apex)
    cp2 = torch.where(ascent, pre_apex, p_td_w)
    cp3 = torch.where(ascent, apex, p_td_w)
    tau = torch.where(ascent, 2.0 * s, 2.0 * s - 1.0)  # segment parameter in [0, 1]

    pos, dpos_dtau, ddpos_dtau2 = cubic_bezier(cp0, cp1, cp2, cp3, tau)
    vel = dpos_dtau / t_seg  # d/dt = (1 / T_seg) d/dtau
    acc = ddpos_dtau2 / t_seg**2  # d2/dt2 = (1 / T_seg^2) d2/dtau2
    if target_vel_w is None:
        return pos, vel, acc

    # sensitivity w = dpos/dp_td (diagonal) and its rate dw/dt along the swing
    w_xy = s**2 * (3.0 - 2.0 * s)  # 3 s^2 - 2 s^3
    dw_xy = 6.0 * s * (1.0 - s) / (2.0 * t_seg)  # d/dt with ds/dt = 1 / T_s = 1 / (2 T_seg)
    z_td_sets_apex = (p_td_w[..., 2:3] >= p_lo_w[..., 2:3]).to(ref.dtype)  # apex = z_td + h
    beta = tau**2 * (3.0 - 2.0 * tau)  # segment smooth step in tau
    dbeta = 6.0 * tau * (1.0 - tau) / t_seg
    # ascent: z = z_lo + (z_apex - z_lo) beta; descent: z = z_apex + (z_td - z_apex) beta
    w_z = torch.where(ascent, beta * z_td_sets_apex, beta + (1.0 - beta) * z_td_sets_apex)
    dw_z = torch.where(ascent, dbeta * z_td_sets_apex, dbeta * (1.0 - z_td_sets_apex))
    w = torch.cat([w_xy.expand_as(pos[..., :2]), w_z], dim=-1)
    dw = torch.cat([dw_xy.expand_as(pos[..., :2]), dw_z], dim=-1)
    v_td = target_vel_w.to(ref.dtype)
    return pos, vel + w * v_td, acc + 2.0 * dw * v_td
