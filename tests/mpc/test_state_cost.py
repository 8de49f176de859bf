"""The state-only rollout cost: the same states give the same cost whatever the footholds' deviation.

Every leg swings for the whole horizon (duty 0): no leg carries a force, so the CoM follows the same
ballistic trajectory whatever the touch-down targets, and a naive warm start (footholds = the
reference) and an RL one (footholds 5 cm ahead, 3 cm inwards) reach identical states. Their full
costs differ by exactly the foothold term, worked out by hand: R_px = R_py = 1000 on every horizon
step of every leg, 1000 (0.05^2 + 0.03^2) x 4 legs x N steps.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc import cpp_kernel
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.encodings import encode
from dls_quadruped.mpc.sampler import SamplingMPC
from dls_quadruped.mpc.samples import decode_samples
from dls_quadruped.mpc.srbd import robot_srbd_model

PHASE = torch.tensor([[0.0, 0.5, 0.5, 0.0], [0.2, 0.7, 0.7, 0.2]])
DP = (0.05, -0.03)
"""[m] the RL warm start's foothold offset from the reference (x, y), every leg and step."""


def _horizon(cfg: SamplerConfig, dp: tuple[float, float]) -> torch.Tensor:
    """(2, D) encoded: f 1.5 Hz, duty 0 (every leg swings), footholds offset by ``dp``, no force offsets."""
    a = torch.zeros(2, cfg.horizon, 28)
    a[..., 0:4] = 1.5
    a[..., 8:16:2], a[..., 9:16:2] = dp[0], dp[1]
    return encode(a, cfg.encoding)


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
def test_same_states_same_state_cost_whatever_the_footholds(kernel, standing):
    if kernel == "cpp" and cpp_kernel.load() is None:
        pytest.skip("no C++ compiler for the MPC kernel")
    cfg = SamplerConfig(num_samples=8, horizon=6, kernel=kernel, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0, sigma_F=0.0)
    state, refs = standing(2)
    naive, rl = _horizon(cfg, (0.0, 0.0)), _horizon(cfg, DP)
    base_xy = state.com_pos_w[:, :2] - torch.tensor(robot_srbd_model().com_offset_b[:2])
    dec = decode_samples(naive[:, None], PHASE, base_xy, torch.zeros(2), torch.zeros(2, 4), cfg)
    assert not dec["contact"].any()  # duty 0: no stance, no force
    refs = Refs(refs.com_height_w, refs.lin_vel_w, refs.yaw_rate, dec["foot_target_w"][:, 0, 0])  # naive = reference
    out = {}
    for name, ws in (("naive", naive), ("rl", rl)):
        mpc = SamplingMPC(cfg, seed=0)
        mpc.record_step_costs = True
        out[name] = mpc.solve(state, refs, [ws], phase=PHASE, base_xy_w=base_xy, base_yaw=torch.zeros(2))
    a, b = out["naive"], out["rl"]
    assert (a.best_input_cost == 0).all()  # the naive warm start's footholds are the reference
    expected = 1000.0 * (DP[0] ** 2 + DP[1] ** 2) * 4 * cfg.horizon
    torch.testing.assert_close(b.best_input_cost, torch.full((2,), expected), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(b.best_state_cost, a.best_state_cost, rtol=1e-5, atol=1e-3)  # the fair comparison
    torch.testing.assert_close(b.best_cost - a.best_cost, torch.full((2,), expected), rtol=1e-3, atol=1e-2)
    assert (a.best_state_cost > 100).all()  # falling from 0.33 m at 0.5 m/s below the command is costly: not trivial
    # per horizon step: the input part is the foothold term of that step, the rest is the state's
    torch.testing.assert_close(b.step_input_costs, torch.full((2, cfg.horizon), expected / cfg.horizon))
    torch.testing.assert_close(b.step_costs - b.step_input_costs, a.step_costs - a.step_input_costs)


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
def test_rollout_state_terms_are_the_ballistic_fall_worked_out_by_hand(kernel, standing):
    """Duty 0: the CoM falls freely from rest, so with explicit Euler (``srbd.srbd_step``) and t_k = k dt,
    v_z,k = -g k dt and z_k - z_0 = -g dt^2 k (k - 1) / 2, v_x stays 0 against the 0.5 m/s command, the
    attitude and rates stay 0: the terms are Q_z sum (g dt^2 k (k-1) / 2)^2, Q_vx N 0.25, Q_vz sum (g k dt)^2
    and 0 for the rest, and they add up to the state cost the kernel (C++ or torch) minimised."""
    if kernel == "cpp" and cpp_kernel.load() is None:
        pytest.skip("no C++ compiler for the MPC kernel")
    from dls_quadruped.mpc.cost import STATE_TERMS

    cfg = SamplerConfig(num_samples=8, horizon=6, kernel=kernel, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0, sigma_F=0.0)
    state, refs = standing(2)
    mpc = SamplingMPC(cfg, seed=0)
    mpc.record_step_costs = True
    base_xy = state.com_pos_w[:, :2] - torch.tensor(robot_srbd_model().com_offset_b[:2])
    res = mpc.solve(state, refs, [_horizon(cfg, DP)], phase=PHASE, base_xy_w=base_xy, base_yaw=torch.zeros(2))
    g, dt, w = robot_srbd_model().gravity, cfg.dt, cfg.weights
    k = torch.arange(1, cfg.horizon + 1, dtype=torch.float64)
    expected = dict.fromkeys(STATE_TERMS, 0.0)
    expected["z"] = w.z * float(((g * dt**2 * k * (k - 1) / 2) ** 2).sum())
    expected["vx"] = w.vx * cfg.horizon * 0.5**2
    expected["vz"] = w.vz * float(((g * k * dt) ** 2).sum())
    got = dict(zip(STATE_TERMS, res.state_terms[0].tolist(), strict=True))
    for name, value in expected.items():
        assert got[name] == pytest.approx(value, rel=1e-4, abs=1e-3), name
    assert expected["z"] > 10 and expected["vz"] > 10  # the fall is costly: the hand values are not trivial
    torch.testing.assert_close(res.state_terms.sum(-1), res.best_state_cost, rtol=1e-4, atol=1e-3)
    mpc.record_step_costs = False  # the fast path records no terms
    again = mpc.solve(state, refs, [_horizon(cfg, DP)], phase=PHASE, base_xy_w=base_xy, base_yaw=torch.zeros(2))
    assert torch.isnan(again.state_terms).all()
