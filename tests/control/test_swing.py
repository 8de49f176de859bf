"""Tests of the two-segment cubic Bézier swing trajectory (thesis Appendix B)."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.control.swing import (
    MIN_SWING_DURATION,
    cubic_bezier,
    swing_reference,
)

P_LO = torch.tensor([0.10, -0.05, 0.02])
P_TD = torch.tensor([0.30, 0.05, 0.00])
H = 0.06
T_S = 0.4 / 1.5  # (1 - d) / f for d = 0.6, f = 1.5 [s]


def test_bezier_hand_worked_midpoint():
    """t = 1/2 weights the control points 1/8, 3/8, 3/8, 1/8; derivatives by hand."""
    cp = [torch.tensor([0.0, 0.0]), torch.tensor([1.0, 2.0]), torch.tensor([3.0, 2.0]), torch.tensor([4.0, 0.0])]
    b, db, ddb = cubic_bezier(*cp, torch.tensor(0.5))
    # (cp0 + 3 cp1 + 3 cp2 + cp3) / 8 = ((0 + 3 + 9 + 4) / 8, (0 + 6 + 6 + 0) / 8) = (2, 1.5)
    torch.testing.assert_close(b, torch.tensor([2.0, 1.5]))
    # B'(1/2) = 3/4 [(cp1 - cp0) + 2 (cp2 - cp1) + (cp3 - cp2)] = 3/4 [(1,2) + (4,0) + (1,-2)] = (4.5, 0)
    torch.testing.assert_close(db, torch.tensor([4.5, 0.0]))
    # B''(1/2) = 3 [(cp2 - 2 cp1 + cp0) + (cp3 - 2 cp2 + cp1)] = 3 [(1,-2) + (-1,-2)] = (0, -12)
    torch.testing.assert_close(ddb, torch.tensor([0.0, -12.0]))


def test_bezier_end_points_and_tangents():
    """B(0) = cp0, B(1) = cp3, B'(0) = 3 (cp1 - cp0), B'(1) = 3 (cp3 - cp2)."""
    cp = torch.randn(4, 5, 3, generator=torch.Generator().manual_seed(0))
    b0, db0, _ = cubic_bezier(cp[0], cp[1], cp[2], cp[3], torch.tensor(0.0))
    b1, db1, _ = cubic_bezier(cp[0], cp[1], cp[2], cp[3], torch.tensor(1.0))
    torch.testing.assert_close(b0, cp[0])
    torch.testing.assert_close(b1, cp[3])
    torch.testing.assert_close(db0, 3 * (cp[1] - cp[0]))
    torch.testing.assert_close(db1, 3 * (cp[3] - cp[2]))


def _ref(s, dtype=torch.float32, t_s=T_S):
    s = torch.as_tensor(s, dtype=dtype)
    return swing_reference(P_LO.to(dtype).expand(*s.shape, 3), P_TD.to(dtype).expand(*s.shape, 3), H, s, t_s)


def test_end_points_and_zero_end_velocities():
    pos, vel, _ = _ref([0.0, 1.0])
    torch.testing.assert_close(pos[0], P_LO)
    torch.testing.assert_close(pos[1], P_TD)
    torch.testing.assert_close(vel, torch.zeros(2, 3))


def test_apex_height_and_position():
    """At s = 1/2: xy midpoint, z = max(z_lo, z_td) + h = 0.02 + 0.06, zero vertical velocity."""
    pos, vel, _ = _ref([0.5])
    torch.testing.assert_close(pos[0], torch.tensor([0.20, 0.0, 0.08]))
    assert abs(vel[0, 2].item()) < 1e-6
    # Apex is the highest point of the swing.
    pos_all, _, _ = _ref(torch.linspace(0, 1, 201))
    assert pos_all[:, 2].max().item() == pytest.approx(0.08, abs=1e-6)


def test_c1_at_apex():
    """Velocity just before and just after the apex agree (left/right segment evaluated)."""
    eps = 1e-9
    _, v_left, _ = _ref([0.5 - eps], dtype=torch.float64)
    _, v_right, _ = _ref([0.5], dtype=torch.float64)
    torch.testing.assert_close(v_left, v_right, atol=1e-6, rtol=0)
    # Hand value: horizontal speed at the apex = 3 (D/4) / T_seg = 1.5 D / T_s.
    d_xy = (P_TD.double() - P_LO.double())[:2]
    torch.testing.assert_close(v_right[0, :2], 1.5 * d_xy / T_S, atol=1e-9, rtol=0)
    assert v_right[0, 2].item() == 0.0


def test_horizontal_motion_is_single_smoothstep():
    """xy(s) = p_lo + D (3 s^2 - 2 s^3) across both segments (the de Casteljau split)."""
    s = torch.linspace(0, 1, 101, dtype=torch.float64)
    pos, _, _ = _ref(s, dtype=torch.float64)
    expected = P_LO[:2].double() + (P_TD - P_LO)[:2].double() * (3 * s**2 - 2 * s**3).unsqueeze(-1)
    torch.testing.assert_close(pos[:, :2], expected)


@pytest.mark.parametrize("t_s", [T_S, 0.1, 0.7])
def test_derivatives_match_finite_differences_in_time(t_s):
    """vel, acc vs central differences of pos w.r.t. time t = s T_s (away from the apex kink in acc)."""
    dt = 1e-6
    s = torch.tensor([0.05, 0.2, 0.37, 0.49, 0.51, 0.66, 0.8, 0.95], dtype=torch.float64)
    ds = dt / t_s
    pos_p, vel_p, _ = _ref(s + ds, torch.float64, t_s)
    pos_m, vel_m, _ = _ref(s - ds, torch.float64, t_s)
    _, vel, acc = _ref(s, torch.float64, t_s)
    torch.testing.assert_close(vel, (pos_p - pos_m) / (2 * dt), atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(acc, (vel_p - vel_m) / (2 * dt), atol=1e-4, rtol=1e-6)
    # The scaling is 1/T_seg, not 1/T_s: the FD check above fails with the wrong factor; also
    # halving T_s doubles velocity and quadruples acceleration at the same progress.
    _, vel2, acc2 = _ref(s, torch.float64, t_s / 2)
    torch.testing.assert_close(vel2, 2 * vel)
    torch.testing.assert_close(acc2, 4 * acc)


def test_clamping_of_progress_and_duration():
    pos, _, _ = _ref([-0.3, 1.7])
    torch.testing.assert_close(pos[0], P_LO)
    torch.testing.assert_close(pos[1], P_TD)
    _, vel0, acc0 = _ref([0.3], t_s=0.0)
    _, vel_min, acc_min = _ref([0.3], t_s=MIN_SWING_DURATION)
    assert torch.isfinite(vel0).all() and torch.isfinite(acc0).all()
    torch.testing.assert_close(vel0, vel_min)
    torch.testing.assert_close(acc0, acc_min)


def test_touch_down_higher_than_lift_off():
    """Apex above the higher end point (stepping up a 10 cm step)."""
    p_td = torch.tensor([0.3, 0.0, 0.10])
    pos, _, _ = swing_reference(P_LO, p_td, 0.05, torch.tensor(0.5), 0.3)
    assert pos[2].item() == pytest.approx(0.15, abs=1e-6)


def test_batched_equals_per_row():
    """(B, 4, 3) batch with per-element T_s and progress equals element-wise calls."""
    g = torch.Generator().manual_seed(1)
    p_lo = torch.randn(5, 4, 3, generator=g) * 0.2
    p_td = torch.randn(5, 4, 3, generator=g) * 0.2
    s = torch.rand(5, 4, generator=g)
    t_s = 0.1 + torch.rand(5, 4, generator=g)
    h = 0.04 + 0.04 * torch.rand(5, 4, generator=g)
    pos, vel, acc = swing_reference(p_lo, p_td, h, s, t_s)
    assert pos.shape == vel.shape == acc.shape == (5, 4, 3)
    for b in range(5):
        for leg in range(4):
            p1, v1, a1 = swing_reference(p_lo[b, leg], p_td[b, leg], h[b, leg], s[b, leg], t_s[b, leg])
            torch.testing.assert_close(pos[b, leg], p1)
            torch.testing.assert_close(vel[b, leg], v1)
            torch.testing.assert_close(acc[b, leg], a1)


def test_dtype_preserved():
    pos, vel, acc = _ref([0.3], dtype=torch.float64)
    assert pos.dtype == vel.dtype == acc.dtype == torch.float64
    pos, _, _ = _ref([0.3])
    assert pos.dtype == torch.float32


# ---------------------------------------------------------------- moving touch-down target (issue 12 item 9a)

V_TD = torch.tensor([0.5, -0.2, 0.1], dtype=torch.float64)  # target velocity [m/s]


def _moving(t: torch.Tensor, z_td0: float, v_td=V_TD):
    """Reference at time t while the target moves from P_TD (z = z_td0) at V_TD; progress s = t / T_s."""
    p_td0 = P_TD.double().clone()
    p_td0[2] = z_td0
    t = torch.as_tensor(t, dtype=torch.float64)
    p_td = p_td0 + t.unsqueeze(-1) * V_TD
    return swing_reference(P_LO.double().expand(*t.shape, 3), p_td, H, t / T_S, T_S, v_td)


@pytest.mark.parametrize("z_td0", [0.0, 0.05])  # apex set by the lift-off height / by the (rising) target
def test_moving_target_derivatives_are_total_time_derivatives(z_td0):
    """With target_vel_w, vel and acc are the time derivatives of the reference evaluated along the moving
    target (central differences of pos(t) = swing_reference(p_lo, p_td(t), s(t))), in every axis."""
    t = torch.tensor([0.01, 0.05, 0.1, 0.125, 0.14, 0.17, 0.23, 0.26], dtype=torch.float64)
    if z_td0 == 0.0:  # z_td(t) = 0.1 t crosses z_lo = 0.02 at t = 0.2 (the max() kink): stay clear of it
        t = t[(t - 0.2).abs() > 0.02]
    h = 1e-5
    pos_p, vel_p, _ = _moving(t + h, z_td0)
    pos_m, vel_m, _ = _moving(t - h, z_td0)
    _, vel, acc = _moving(t, z_td0)
    torch.testing.assert_close(vel, (pos_p - pos_m) / (2 * h), atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(acc, (vel_p - vel_m) / (2 * h), atol=1e-3, rtol=1e-5)
    # the static-target reference misses the target's motion: its velocity is off by w(s) v_td
    _, vel_static, _ = _moving(t, z_td0, v_td=None)
    assert (vel - vel_static).abs().max() > 0.1


def test_moving_target_terms_vanish_at_lift_off_and_match_the_target_at_touch_down():
    s = torch.tensor([0.0, 1.0], dtype=torch.float64)
    p_lo, p_td = P_LO.double().expand(2, 3), P_TD.double().expand(2, 3)
    pos, vel, acc = swing_reference(p_lo, p_td, H, s, T_S, V_TD.expand(2, 3))
    pos0, _, acc0 = swing_reference(p_lo, p_td, H, s, T_S)
    torch.testing.assert_close(pos, pos0)  # the position is the same curve
    torch.testing.assert_close(vel[0], torch.zeros(3, dtype=torch.float64))  # lift-off: at rest
    torch.testing.assert_close(vel[1], V_TD)  # touch-down: moving with the target (z_td < z_lo here: w_z = 1)
    torch.testing.assert_close(acc[0], acc0[0])  # 2 dw/dt v_td = 0 at both ends (dw/ds = 6 s (1 - s))
    # a target at rest changes nothing anywhere
    s_all = torch.linspace(0, 1, 21, dtype=torch.float64)
    still = swing_reference(P_LO.double().expand(21, 3), P_TD.double().expand(21, 3), H, s_all, T_S,
                            torch.zeros(21, 3, dtype=torch.float64))
    static = swing_reference(P_LO.double().expand(21, 3), P_TD.double().expand(21, 3), H, s_all, T_S)
    for a, b in zip(still, static, strict=True):
        torch.testing.assert_close(a, b)


def test_target_tracker_follows_a_staircase_ramp_without_lag():
    """The low-level controller's alpha-beta tracker fed a target moving at 0.5 m/s but updated every 2
    physics steps (the MPC's 100 Hz): after 0.3 s its velocity is the ramp's, its position within half
    an update of the staircase (<= 2.5 mm); a jump settles within ~0.2 s (critically damped)."""
    from dls_quadruped.control.lowlevel import LowLevelConfig, LowLevelController

    ctrl = LowLevelController(1, LowLevelConfig(target_bandwidth=40.0), dt=0.005)
    v = torch.tensor([0.5, -0.1], dtype=torch.float64)
    p0 = torch.tensor([[0.3, 0.1], [0.3, -0.1], [-0.2, 0.1], [-0.2, -0.1]], dtype=torch.float64)
    target = torch.zeros(1, 4, 3, dtype=torch.float64)
    for k in range(120):  # 0.6 s
        if k % 2 == 0:  # a new target every 10 ms
            target[0, :, :2] = p0 + k * 0.005 * v
            target[0, :, 2] = 0.0265
        tracked, vel = ctrl.track_target(target)
        if k >= 60:
            torch.testing.assert_close(vel[0, :, :2], v.expand(4, 2), atol=0.03, rtol=0)
            assert (tracked[0, :, :2] - target[0, :, :2]).norm(dim=-1).max() <= 0.0026
            assert torch.equal(tracked[0, :, 2], target[0, :, 2])  # the vertical target passes through
            assert torch.equal(vel[0, :, 2], torch.zeros(4, dtype=torch.float64))
    # a 5 cm jump of the target: settled to < 1 mm and < 2 cm/s within 0.2 s
    jumped = target.clone()
    jumped[0, :, 0] += 0.05
    for k in range(40):
        tracked, vel = ctrl.track_target(jumped)
    assert (tracked[0, :, :2] - jumped[0, :, :2]).abs().max() < 1e-3 and vel.abs().max() < 0.02
    # bandwidth 0: the raw target, no velocity (the reference before issue 12)
    raw = LowLevelController(1, LowLevelConfig(target_bandwidth=0.0), dt=0.005).track_target(target)
    assert raw[0] is target and raw[1] is None
    with pytest.raises(ValueError, match="target_bandwidth"):
        LowLevelController(1, LowLevelConfig(target_bandwidth=100.0), dt=0.005)


@pytest.fixture(scope="module")
def swing_runs():
    """The model-based baseline at 0.5 m/s (M = 2000, 3 s), swing reference with and without the tracker."""
    from dls_quadruped.bench.swing import measure

    return {bw: measure(vx=0.5, seconds=3.0, samples=2000, bandwidth=bw) for bw in (0.0, 40.0)}


def test_touch_down_error_drops_with_the_moving_target_reference(swing_runs):
    """Walking at 0.5 m/s the touch-down target moves with the body: the reference that ignores its motion
    leaves the foot ~3.5 cm behind at touch-down (docs/mpc.md), the tracked one < 1.2 cm."""
    old, new = swing_runs[0.0], swing_runs[40.0]
    assert not old["fallen"] and not new["fallen"] and new["touch_downs"] >= 10
    assert old["touch_down_rms_m"] > 0.025, old
    assert new["touch_down_rms_m"] < 0.012, new
    assert new["swing_tracking_rms_m"] < 0.5 * old["swing_tracking_rms_m"]


def test_target_tracker_recovers_from_a_non_finite_target():
    from dls_quadruped.control.lowlevel import LowLevelConfig, LowLevelController

    ctrl = LowLevelController(2, LowLevelConfig(target_bandwidth=40.0), dt=0.005)
    target = torch.full((2, 4, 3), 0.1, dtype=torch.float64)
    ctrl.track_target(target)
    bad = target.clone()
    bad[1, 2, 0] = float("nan")
    ctrl.track_target(bad)
    tracked, vel = ctrl.track_target(target)  # robot 1 restarts at the finite target, robot 0 never noticed
    torch.testing.assert_close(tracked, target)
    assert torch.equal(vel, torch.zeros_like(vel))
