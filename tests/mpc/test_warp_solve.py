"""The device solve (mpc/warp_solve.py) on Warp's CPU device: its result, fallbacks, graph and host reads.

* its winner is the ``cpp`` kernel's on the same seed and inputs, and its decoded result is the torch decoding
  (``SamplingMPC.decode_winners``) of that winner, field by field within float32 round-off;
* a robot with a non-finite input, a phase outside [0, 1] or a non-finite warm start keeps its previous action
  (+inf costs, index -1), or gets warm start 0 decoded when there is no previous solve;
* a solve replayed from the captured graph returns what the launched solve returns, bit for bit;
* after warm-up a solve (with the naive warm start) makes no host read (``core/sync_probe.py``).
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from dls_quadruped.core.sync_probe import sync_probe
from dls_quadruped.mpc import cpp_kernel, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.kernel import KernelInputs
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC

pytest.importorskip("warp")

ACTION = ("f", "d", "contact", "foot_target_w", "force_w", "p_h", "F_h", "best_encoded", "contact_horizon")


def _solves(perturbed_standing, cfg: SamplerConfig, b: int, solves: int, capture: bool = True,
            nan_at: int | None = None, seed: int = 5) -> tuple[SamplingMPC, list[MPCResult]]:
    """``solves`` chained solves (naive warm start 70 %, a 1.8 Hz trot 30 %); at ``nan_at`` robot 0's velocity is NaN
    and robot B-1's velocity reference infinite."""
    state, refs, phase = perturbed_standing(b, 3)
    mpc = SamplingMPC(cfg, seed=seed)
    mpc.capture = capture
    default, trot = warm_start.nominal_trot(b, cfg), warm_start.nominal_trot(b, cfg, freq=1.8)
    out = []
    for k in range(solves):
        s, r = state, refs
        if k == nan_at:
            s = dataclasses.replace(state, com_vel_w=state.com_vel_w.clone())
            s.com_vel_w[0, 0] = float("nan")
            r = dataclasses.replace(refs, lin_vel_w=refs.lin_vel_w.clone())
            r.lin_vel_w[-1, 1] = float("inf")
        out.append(mpc.solve(s, r, [mpc.naive_warm_start(default), trot], proportions=(0.7, 0.3), phase=phase))
        phase = (phase + 0.02) % 1.0
    return mpc, out


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and bool(torch.equal(a.isnan(), b.isnan())) and \
        bool(torch.equal(a[~a.isnan()], b[~b.isnan()])) if a.is_floating_point() else torch.equal(a, b)


@pytest.mark.parametrize(("enc_p", "enc_F", "b"), [("first", "spline", 4), ("discrete", "discrete", 3),
                                                   ("spline", "spline", 2)])
def test_device_solve_is_the_cpp_winner_decoded_by_torch(enc_p, enc_F, b, perturbed_standing):
    if cpp_kernel.load() is None:
        pytest.skip("no C++ compiler: nothing to compare with")
    cfg = SamplerConfig(num_samples=400, horizon=10, encoding_p=enc_p, encoding_F=enc_F, kernel="warp")
    mpc, results = _solves(perturbed_standing, cfg, b, 3)
    work = mpc.last_device_solve
    res = results[-1]
    assert not res.fallback.any() and res.reason == ""
    c = work.clean
    refs = Refs(c["h_ref"][:, 0], c["vel_ref"], c["wz_ref"][:, 0], c["foothold"].view(b, 4, 3))
    inp = KernelInputs(work.seed[0].clone(), c["warm"], work.group, work.perturb, c["x"], c["phase"], c["base_xy"],
                       c["base_yaw"][:, 0], c["terrain_z"], refs)
    cpp = cpp_kernel.cpp_costs(inp, cfg, mpc.model, cpp_kernel.load())
    assert torch.equal(res.best_index, cpp.min(dim=1).indices)
    torch.testing.assert_close(res.best_cost, cpp.min(dim=1).values, rtol=1e-5, atol=0.0)
    ref = mpc.decode_winners(inp, res.best_index, res.best_cost, res.initial_cost)
    for name in (*ACTION, "step_input_costs", "best_input_cost", "warm_start_index"):
        got, want = getattr(res, name), getattr(ref, name)
        if got.is_floating_point():
            torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-4, msg=name)
        else:
            assert torch.equal(got, want), name
    assert torch.isnan(res.step_costs).all() and torch.isnan(res.state_terms).all()
    assert len({int(r.best_index[0]) for r in results}) > 1  # a new seed every solve: other winners


def test_fallbacks_keep_the_previous_action(perturbed_standing):
    cfg = SamplerConfig(num_samples=300, horizon=10, kernel="warp")
    mpc, results = _solves(perturbed_standing, cfg, 3, 3, nan_at=1)
    before, bad, after = results
    assert bad.fallback.tolist() == [True, False, True] and not after.fallback.any()
    for name in ACTION:
        for robot in (0, 2):
            assert torch.equal(getattr(bad, name)[robot], getattr(before, name)[robot]), name
        assert not torch.equal(getattr(bad, name)[1], getattr(before, name)[1]) or name.startswith("contact")
    assert bad.best_index.tolist()[0] == -1 and bad.warm_start_index.tolist()[2] == -1
    assert torch.isposinf(bad.best_cost[[0, 2]]).all() and torch.isposinf(bad.step_input_costs[[0, 2]]).all()
    assert torch.isfinite(bad.best_cost[1])
    assert mpc.fallback_report() == ""


def test_first_solve_fallback_is_warm_start_zero_and_the_report_names_it(perturbed_standing):
    cfg = SamplerConfig(num_samples=200, horizon=10, kernel="warp")
    mpc, results = _solves(perturbed_standing, cfg, 3, 1, nan_at=0)
    res = results[0]
    assert res.fallback.tolist() == [True, False, True]
    default = warm_start.nominal_trot(3, cfg)
    torch.testing.assert_close(res.best_encoded[[0, 2]], default[[0, 2]], rtol=0.0, atol=0.0)
    report = mpc.fallback_report()
    assert "state of robots [0] is not finite" in report and "refs.lin_vel_w of robots [2]" in report
    state, refs, phase = perturbed_standing(3, 3)
    phase[1, 2] = 1.5  # outside the gait cycle: the torch path raises, the device path flags the robot
    bad = mpc.solve(state, refs, [mpc.naive_warm_start(default)], phase=phase)
    assert bad.fallback.tolist() == [False, True, False] and "phase of robots [1]" in mpc.fallback_report()
    ws = default.clone()
    ws[0, 9] = float("inf")
    assert mpc.solve(state, refs, [ws], phase=phase % 1.0).fallback.tolist() == [True, False, False]
    assert "warm_starts of robots [0]" in mpc.fallback_report()


def test_captured_solve_is_the_launched_solve_bit_for_bit(perturbed_standing):
    cfg = SamplerConfig(num_samples=500, horizon=10, kernel="warp")
    mpc_c, captured = _solves(perturbed_standing, cfg, 4, 5, capture=True, nan_at=2)
    mpc_l, launched = _solves(perturbed_standing, cfg, 4, 5, capture=False, nan_at=2)
    (graph,) = [w.graph for w in mpc_c.device_solver.solves.values()]
    assert graph.captures == 1 and graph.graph is not None and graph.error is None
    assert all(w.graph.graph is None for w in mpc_l.device_solver.solves.values())
    for a, b in zip(captured, launched, strict=True):
        for f in dataclasses.fields(MPCResult):
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert _same(x, y) if isinstance(x, torch.Tensor) else x == y, f.name
    other = _solves(perturbed_standing, cfg, 4, 2, seed=6)[1]  # another MPC seed: other noise
    assert not torch.equal(other[1].best_encoded, captured[1].best_encoded)


def test_no_host_read_per_solve_after_warm_up(perturbed_standing):
    cfg = SamplerConfig(num_samples=300, horizon=10, kernel="warp")
    b = 4
    state, refs, phase = perturbed_standing(b, 3)
    mpc = SamplingMPC(cfg, seed=1)
    default, trot = warm_start.nominal_trot(b, cfg), warm_start.nominal_trot(b, cfg, freq=1.8)
    frame = {"base_xy_w": torch.zeros(b, 2), "base_yaw": torch.zeros(b), "terrain_z_w": torch.zeros(b, 4)}

    def solve() -> MPCResult:
        return mpc.solve(state, refs, [mpc.naive_warm_start(default), trot], proportions=(0.5, 0.5), phase=phase,
                         **frame)

    for _ in range(3):  # build, launch, capture
        solve()

    def no_solve(*args, **kwargs):  # on CUDA torch.linalg.solve waits for its status: none per solve
        raise AssertionError("torch.linalg.solve called in a solve")

    with sync_probe() as report, pytest.MonkeyPatch.context() as patch:
        patch.setattr(torch.linalg, "solve", no_solve)
        for _ in range(4):
            result = solve()
    assert report.total == 0, report.by_site()
    assert mpc.uses_device_solve(2) and not result.fallback.any()
    with sync_probe() as control:  # the probe does see the torch path's reads
        mpc.fused = False
        solve()
    assert control.total > 0


def test_arbitration_takes_the_torch_path():
    mpc = SamplingMPC(SamplerConfig(num_samples=100, kernel="warp", switching_cost=10.0))
    assert mpc.uses_device_solve(1) and not mpc.uses_device_solve(2)
    mpc.record_step_costs = True
    assert mpc.uses_device_solve(1)  # the step costs are rolled out on the device path
    assert not SamplingMPC(SamplerConfig(num_samples=100)).uses_device_solve(1)  # cpp on the CPU


def test_step_costs_on_the_device_path_are_the_torch_decodings(perturbed_standing):
    """With ``record_step_costs`` the device solve's step costs and state terms are those the torch path's
    ``decode_winners`` computes for the same winner (re-drawn from the seed and layout by torch), the fallback
    robot's +inf; the solve reads nothing back to the host."""
    cfg = SamplerConfig(num_samples=300, horizon=10, kernel="warp")
    mpc, _ = _solves(perturbed_standing, cfg, 3, 2, nan_at=1)
    mpc.record_step_costs = True
    state, refs, phase = perturbed_standing(3, 3)
    ws = [mpc.naive_warm_start(warm_start.nominal_trot(3, cfg)), warm_start.nominal_trot(3, cfg, freq=1.8)]
    bad = dataclasses.replace(state, com_vel_w=state.com_vel_w.clone())
    bad.com_vel_w[2, 1] = float("nan")
    mpc.solve(bad, refs, ws, proportions=(0.7, 0.3), phase=phase)  # builds and launches this layout
    with sync_probe() as report:
        res = mpc.solve(bad, refs, ws, proportions=(0.7, 0.3), phase=phase)
    assert report.total == 0, report.by_site()
    assert res.fallback.tolist() == [False, False, True]
    work = mpc.last_device_solve
    c = work.clean
    torch_refs = Refs(c["h_ref"][:, 0], c["vel_ref"], c["wz_ref"][:, 0], c["foothold"].view(3, 4, 3))
    inp = KernelInputs(work.seed[0].clone(), c["warm"], work.group, work.perturb, c["x"], c["phase"], c["base_xy"],
                       c["base_yaw"][:, 0], c["terrain_z"], torch_refs)
    ref = mpc.decode_winners(inp, res.best_index.clamp_min(0), res.best_cost, res.initial_cost)
    for name in ("step_costs", "state_terms"):
        got, want = getattr(res, name), getattr(ref, name)
        assert torch.isfinite(want[:2]).all() and torch.isposinf(got[2]).all(), name
        torch.testing.assert_close(got[:2], want[:2], rtol=1e-4, atol=1e-3, msg=name)
    torch.testing.assert_close(res.step_costs[:2].sum(-1), res.best_cost[:2], rtol=1e-4, atol=1e-3)


def test_inference_mode_then_not(perturbed_standing):
    """The closed loop solves in inference mode, a test or a training step outside it: the same workspace serves
    both (its buffers are made outside inference mode)."""
    cfg = SamplerConfig(num_samples=100, horizon=10, kernel="warp")
    state, refs, phase = perturbed_standing(2, 3)
    mpc = SamplingMPC(cfg)
    ws = warm_start.nominal_trot(2, cfg)
    with torch.inference_mode():
        first = mpc.solve(state, refs, [ws], phase=phase)
    second = mpc.solve(state, refs, [ws], phase=phase)
    assert len(mpc.device_solver.solves) == 1 and not first.fallback.any() and not second.fallback.any()
    assert not torch.equal(first.best_encoded, second.best_encoded)  # the counter moved: another draw
