"""Sampling controller: warm-start groups, clipping, determinism, closed loop on the SRBD, bad input."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import rollout_cost_reference
from dls_quadruped.mpc.encodings import encode, encoded_dim
from dls_quadruped.mpc.sampler import SamplingMPC
from dls_quadruped.mpc.samples import decode_samples, group_layout, sample_encoded
from dls_quadruped.mpc.srbd import SRBDState, robot_srbd_model, srbd_step

PHASE = torch.tensor([[0.0, 0.5, 0.5, 0.0], [0.2, 0.7, 0.7, 0.2]])


def _cfg(**kw) -> SamplerConfig:
    return SamplerConfig(**{"num_samples": 400, "horizon": 6, "kernel": "reference", **kw})


def test_group_layout_counts_and_nominal_samples():
    group, perturb, counts = group_layout(10, (0.25, 0.75))
    assert counts == (3, 7)  # 2.5 -> 3 by largest remainder (tie broken by order), 7.5 -> 7
    assert group.tolist() == [0, 0, 0, 1, 1, 1, 1, 1, 1, 1]
    assert perturb.tolist() == [0, 1, 1, 0, 1, 1, 1, 1, 1, 1]
    _, _, counts = group_layout(5, (0.98, 0.01, 0.01))
    assert counts == (3, 1, 1)  # every warm start keeps at least its own sample


def test_sample_zero_of_each_group_is_the_warm_start():
    cfg = _cfg(sigma_F=50.0, sigma_p=0.05)
    ws = torch.stack([warm_start.nominal_trot(2, cfg), warm_start.nominal_trot(2, cfg, freq=2.0)], dim=1)
    group, perturb, counts = group_layout(cfg.num_samples, (0.5, 0.5))
    idx = torch.arange(cfg.num_samples).expand(2, -1)
    samples = sample_encoded(torch.tensor(3), ws, group, perturb, idx, cfg)
    assert torch.equal(samples[:, 0], ws[:, 0]) and torch.equal(samples[:, counts[0]], ws[:, 1])
    assert (samples[:, 1] != ws[:, 0]).any()


def test_samples_respect_table1_limits_after_decoding():
    cfg = _cfg(encoding_p="spline", encoding_F="spline", sigma_f=5.0, sigma_d=1.0, sigma_p=0.5, sigma_F=500.0)
    ws = warm_start.nominal_trot(2, cfg)[:, None]
    group, perturb, _ = group_layout(cfg.num_samples, (1.0,))
    samples = sample_encoded(torch.tensor(0), ws, group, perturb, torch.arange(cfg.num_samples).expand(2, -1), cfg)
    dec = decode_samples(samples, PHASE, torch.zeros(2, 2), torch.tensor([0.0, 1.0]), torch.zeros(2, 4), cfg)
    act = cfg.action
    assert dec["f"].min() >= 0 and dec["f"].max() <= 3 and dec["d"].min() >= 0 and dec["d"].max() <= 1
    p = dec["p_h"]
    assert p[..., 0].min() >= -0.10 and p[..., 0].max() <= 0.15 + 1e-7
    assert p[..., 1].min() >= -0.10 and p[..., 1].max() <= 0.10 + 1e-7
    F = dec["F_h"]
    assert F[..., 2].min() >= 0 and F[..., 2].max() <= act.weight + 1e-3
    assert (F[..., :2].norm(dim=-1) <= act.mu * F[..., 2] + 1e-3).all()
    assert (F[..., :2].norm(dim=-1) > 0.99 * act.mu * F[..., 2]).any()  # the cone clip was active
    Fw = dec["force_w"]  # yaw rotation keeps the cone and F_z
    torch.testing.assert_close(Fw[..., :2].norm(dim=-1), F[..., :2].norm(dim=-1))


def test_sigma_zero_freezes_the_variable():
    cfg = _cfg(sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    ws = warm_start.nominal_trot(2, cfg)[:, None]
    group, perturb, _ = group_layout(cfg.num_samples, (1.0,))
    s = sample_encoded(torch.tensor(0), ws, group, perturb, torch.arange(cfg.num_samples).expand(2, -1), cfg)
    assert torch.equal(s[..., :16], ws[:, :, :16].expand_as(s[..., :16]))  # f, d, first p untouched
    assert (s[..., 16:] != ws[..., 16:]).any()


def test_solve_returns_best_and_is_deterministic(standing_pair):
    state, refs = standing_pair
    cfg = _cfg()
    trot = warm_start.nominal_trot(2, cfg)
    no_force = torch.zeros(2, cfg.horizon, 28)
    no_force[..., 0:4], no_force[..., 4:8] = 1.5, 0.6
    no_force[..., 18:28:3] = -cfg.action.weight  # F_z offsets -m g: F_z clipped to 0 on every leg
    bad = encode(no_force, cfg.encoding)  # no force at all: falls
    results = []
    for _ in range(2):
        mpc = SamplingMPC(cfg, seed=42)
        results.append(mpc.solve(state, refs, [bad, trot], proportions=(0.5, 0.5), phase=PHASE))
    r = results[0]
    assert torch.equal(r.best_encoded, results[1].best_encoded) and torch.equal(r.best_cost, results[1].best_cost)
    assert (r.warm_start_index == 1).all()  # carrying the weight beats falling
    assert (r.best_index >= 100).all()
    # best cost = the reference rollout of the returned encoded sample, and no worse than the warm start's
    b, m = 2, cfg.num_samples
    group, perturb, _ = group_layout(m, (0.5, 0.5))
    ws = torch.stack([bad, trot], dim=1)
    idx = torch.stack([r.best_index, torch.full((b,), 200)], dim=1)  # winner, and warm start 1 itself
    samples = sample_encoded(torch.tensor(0), ws, group, perturb, idx, cfg)  # seed irrelevant at idx 200
    samples[:, 0] = r.best_encoded
    base_yaw = torch.zeros(b)
    dec = decode_samples(samples, PHASE, state.com_pos_w[:, :2] - torch.tensor(robot_srbd_model().com_offset_b[:2]),
                         base_yaw, torch.zeros(b, 4), cfg)
    costs = rollout_cost_reference(state.as_vector(), dec["contact"], dec["foot_target_w"], dec["force_w"], refs,
                                   robot_srbd_model(), cfg.weights, cfg.dt)
    torch.testing.assert_close(costs[:, 0], r.best_cost, rtol=1e-5, atol=1e-3)
    assert (r.best_cost <= costs[:, 1]).all()
    # first action is the decoded winner at step 0
    torch.testing.assert_close(r.force_w, dec["force_w"][:, 0, 0])
    assert torch.equal(r.contact, dec["contact"][:, 0, 0])
    assert r.initial_cost.shape == (2,) and (r.initial_cost > 0).all()  # 0.5 m/s command, standing still
    assert not r.fallback.any() and r.reason == ""


def test_closed_loop_on_srbd_tracks_height_and_velocity(standing):
    """The MPC driving the SRBD model itself (perfect model): stays up, accelerates towards 0.5 m/s."""
    state, refs = standing(1)
    cfg = _cfg(num_samples=256, horizon=10, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    mpc = SamplingMPC(cfg, seed=0)
    model = mpc.model
    default = warm_start.nominal_trot(1, cfg)
    phase = torch.tensor([[0.0, 0.5, 0.5, 0.0]])
    x = state.as_vector()
    for _ in range(40):  # 0.4 s at 100 Hz, two SRBD half-steps per solve
        st = SRBDState.from_vector(x)
        refs.foothold_w[:, :, :2] = st.com_pos_w[:, None, :2] + torch.tensor([[0.24, 0.134], [0.24, -0.134],
                                                                           [-0.24, 0.134], [-0.24, -0.134]])
        r = mpc.solve(st, refs, [mpc.naive_warm_start(default)], phase=phase)
        x = srbd_step(x, r.contact, r.foot_target_w, r.force_w, model, cfg.mpc_period)
        phase = torch.remainder(phase + r.f * cfg.mpc_period, 1.0)
    assert abs(x[0, 2].item() - 0.33) < 0.03
    assert x[0, 3].item() > 0.2  # moving forward
    assert x[0, 6:8].abs().max() < 0.15  # roll, pitch small


def test_nan_state_falls_back_to_previous_solution(standing_pair):
    state, refs = standing_pair
    cfg = _cfg()
    mpc = SamplingMPC(cfg, seed=1)
    ws = warm_start.nominal_trot(2, cfg)
    first = mpc.solve(state, refs, [ws], phase=PHASE)
    broken = SRBDState(state.com_pos_w.clone(), state.com_vel_w.clone(), state.euler.clone(), state.ang_vel_b.clone(),
                       state.foot_pos_w.clone())
    broken.com_vel_w[1, 0] = float("nan")
    r = mpc.solve(broken, refs, [ws], phase=PHASE)
    assert r.fallback.tolist() == [False, True] and "[1]" in r.reason and "previous solution" in r.reason
    assert torch.equal(r.force_w[1], first.force_w[1]) and torch.equal(r.best_encoded[1], first.best_encoded[1])
    assert r.best_index[1] == -1 and r.best_cost[1] == float("inf") and torch.isfinite(r.best_cost[0])
    fresh = SamplingMPC(cfg, seed=1).solve(broken, refs, [ws], phase=PHASE)  # no previous: the warm start
    assert "warm start" in fresh.reason and torch.equal(fresh.best_encoded[1], ws[1])


def test_bad_input_raises_naming_the_argument(standing_pair):
    state, refs = standing_pair
    cfg = _cfg()
    mpc = SamplingMPC(cfg)
    ws = warm_start.nominal_trot(2, cfg)
    dim = encoded_dim(cfg.encoding)
    with pytest.raises(ValueError, match=r"warm_starts\[0\].*\(2, 64\)"):
        mpc.solve(state, refs, [ws[:, :10]], phase=PHASE)
    with pytest.raises(ValueError, match="proportions.*sum to 1"):
        mpc.solve(state, refs, [ws, ws], proportions=(0.5, 0.6), phase=PHASE)
    with pytest.raises(ValueError, match="one entry per warm start"):
        mpc.solve(state, refs, [ws, ws], proportions=(1.0,), phase=PHASE)
    with pytest.raises(ValueError, match="phase"):
        mpc.solve(state, refs, [ws], phase=PHASE[:1])
    with pytest.raises(ValueError, match="foothold_w"):
        bad_refs = type(refs)(refs.com_height_w, refs.lin_vel_w, refs.yaw_rate, refs.foothold_w[:, :3])
        mpc.solve(state, bad_refs, [ws], phase=PHASE)
    with pytest.raises(ValueError, match="finite"):
        mpc.solve(state, refs, [torch.full((dim,), float("nan"))], phase=PHASE)
    with pytest.raises(ValueError, match=r"num_samples \(M = 2\).*3"):
        SamplingMPC(_cfg(num_samples=2)).solve(state, refs, [ws, ws, ws], proportions=(0.2, 0.3, 0.5), phase=PHASE)
    with pytest.raises(ValueError, match="sigma_F must be >= 0"):
        SamplerConfig(sigma_F=-1.0)
    with pytest.raises(ValueError, match="kernel must be one of"):
        SamplerConfig(kernel="jax")
    with pytest.raises(ValueError, match="unknown SamplerConfig keys"):
        SamplerConfig.from_dict({"num_sample": 10})
    with pytest.raises(ValueError, match="com_vel_w"):
        mpc.solve(SRBDState(state.com_pos_w, state.com_vel_w[:, :2], state.euler, state.ang_vel_b, state.foot_pos_w),
                  refs, [ws], phase=PHASE)

