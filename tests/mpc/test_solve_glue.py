"""The fused solve (mpc/solve_glue.py, issue 25) returns exactly what the torch path returns, field by field and bit
for bit: same samples, same winner, same costs, same fallbacks, over a closed loop of solves (the naive warm start
feeds each result into the next solve)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from dls_quadruped.mpc import cpp_kernel, solve_glue, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC


@pytest.fixture(scope="module")
def libs():
    kernel_lib, glue = cpp_kernel.load(), solve_glue.load()
    if kernel_lib is None or glue is None:
        pytest.skip("no C++ compiler: the fused solve is not available")
    return kernel_lib, glue


def _run(perturbed_standing, cfg: SamplerConfig, fused: bool, b: int, solves: int = 5, nan_at: int | None = None,
         frame: bool = False, same_twice: bool = False) -> list[MPCResult]:
    """``solves`` solves with the naive warm start (70 %) and a trot at 1.8 Hz (30 %); every third one records the
    step costs (the fused path then decodes the winner with torch); at ``nan_at`` robot 0's state and robot
    B-1's velocity reference are not finite; ``frame``: pass base_xy_w, base_yaw, terrain_z_w; ``same_twice``: two
    groups of 50 % around the naive warm start instead (their best costs differ by the noise alone)."""
    state, refs, phase = perturbed_standing(b, 3)
    mpc = SamplingMPC(cfg, seed=5)
    mpc.fused = fused
    default, trot = warm_start.nominal_trot(b, cfg), warm_start.nominal_trot(b, cfg, freq=1.8)
    gen = torch.Generator().manual_seed(11)
    out = []
    for k in range(solves):
        s, r = state, refs
        if k == nan_at:
            s = dataclasses.replace(state, com_vel_w=state.com_vel_w.clone())
            s.com_vel_w[0, 0] = float("nan")
            r = dataclasses.replace(refs, lin_vel_w=refs.lin_vel_w.clone())
            r.lin_vel_w[-1, 1] = float("inf")
        kw = {}
        if frame:
            kw = {"base_xy_w": 0.1 * torch.randn(b, 2, generator=gen), "base_yaw": torch.randn(b, generator=gen),
                  "terrain_z_w": 0.05 * torch.rand(b, 4, generator=gen)}
        mpc.record_step_costs = k % 3 == 2
        naive = mpc.naive_warm_start(default)
        ws, props = ([naive, naive], (0.5, 0.5)) if same_twice else ([naive, trot], (0.7, 0.3))
        out.append(mpc.solve(s, r, ws, proportions=props, phase=phase, **kw))
        phase = (phase + 0.02) % 1.0
    return out


def _assert_identical(a: MPCResult, b: MPCResult) -> None:
    for f in dataclasses.fields(MPCResult):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, torch.Tensor):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            same_nan = torch.equal(x.isnan(), y.isnan()) and torch.equal(x[~x.isnan()], y[~y.isnan()])
            assert torch.equal(x, y) or same_nan, f"{f.name}: {x} vs {y}"
        else:
            assert x == y, f.name


@pytest.mark.parametrize(("enc_p", "enc_F", "b"), [("first", "spline", 1), ("first", "spline", 16),
                                                   ("discrete", "discrete", 3), ("spline", "first", 2),
                                                   ("spline", "spline", 5)])
def test_fused_solve_is_the_torch_solve_bit_for_bit(libs, enc_p, enc_F, b, perturbed_standing):
    cfg = SamplerConfig(num_samples=400, horizon=10, encoding_p=enc_p, encoding_F=enc_F)
    for nan_at, frame in ((None, b == 3), (1, b != 3)):
        torch_path = _run(perturbed_standing, cfg, False, b, nan_at=nan_at, frame=frame)
        fused = _run(perturbed_standing, cfg, True, b, nan_at=nan_at, frame=frame)
        for r_torch, r_fused in zip(torch_path, fused, strict=True):
            _assert_identical(r_torch, r_fused)
    assert fused[1].fallback[0] and fused[1].fallback[-1] and "state of robots [0]" in fused[1].reason


def test_fused_solve_full_size_two_threads(libs, perturbed_standing):
    """M = 10 000, N = 10 (the benchmark's size), kernel on 2 threads: still the torch path's result."""
    cfg = SamplerConfig()
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for r_torch, r_fused in zip(_run(perturbed_standing, cfg, False, 2, solves=2),
                                    _run(perturbed_standing, cfg, True, 2, solves=2), strict=True):
            _assert_identical(r_torch, r_fused)
    finally:
        torch.set_num_threads(threads)


def test_fused_solve_counts_the_kernel_and_reuses_its_buffers(libs, standing):
    state, refs = standing(2)
    cfg = SamplerConfig(num_samples=300)
    mpc = SamplingMPC(cfg)
    first = mpc.solve(state, refs, [warm_start.nominal_trot(2, cfg)], phase=torch.zeros(2, 4))
    workspace = mpc.fused_solve.workspaces[(2, 1)]
    second = mpc.solve(state, refs, [mpc.naive_warm_start()], phase=torch.zeros(2, 4))
    assert mpc.fused_solve.workspaces[(2, 1)] is workspace and mpc.kernel_seconds > 0.0
    assert first.best_encoded.data_ptr() != second.best_encoded.data_ptr()  # results are never buffers


def test_without_the_glue_library_the_torch_path_runs(libs, monkeypatch, perturbed_standing):
    cfg = SamplerConfig(num_samples=300)
    expected = _run(perturbed_standing, cfg, False, 2, solves=2)
    monkeypatch.setattr(solve_glue, "load", lambda: None)
    for r_torch, r_fallback in zip(expected, _run(perturbed_standing, cfg, True, 2, solves=2), strict=True):
        _assert_identical(r_torch, r_fallback)


def test_all_finite_matches_torch(libs):
    x = torch.randn(7, 48)
    assert solve_glue.all_finite(x) and solve_glue.all_finite(x.double())
    for bad in (float("nan"), float("inf"), -float("inf")):
        y = x.clone()
        y[6, 47] = bad
        assert not solve_glue.all_finite(y) and not solve_glue.all_finite(y.T)


@pytest.mark.parametrize(("switching_cost", "smoothing"), [(1000.0, 0.0), (0.0, 0.9), (1000.0, 0.5)])
def test_fused_solve_with_arbitration_is_the_torch_solve(libs, switching_cost, smoothing, perturbed_standing):
    """The arbitration between two groups (mpc/arbitration.py) picks the same winners on both paths, with a
    fallback at solve 1, around different and around the same warm start; around the same one it picks other
    winners than the plain argmin (the check is not vacuous)."""
    cfg = SamplerConfig(num_samples=400, horizon=10, switching_cost=switching_cost, group_cost_smoothing=smoothing)
    for nan_at, same in ((None, False), (1, True)):
        torch_path = _run(perturbed_standing, cfg, False, 5, nan_at=nan_at, same_twice=same)
        fused = _run(perturbed_standing, cfg, True, 5, nan_at=nan_at, same_twice=same)
        for r_torch, r_fused in zip(torch_path, fused, strict=True):
            _assert_identical(r_torch, r_fused)
    plain = _run(perturbed_standing, SamplerConfig(num_samples=400, horizon=10), True, 5, nan_at=1, same_twice=True)
    assert any(not torch.equal(a.best_index, p.best_index) for a, p in zip(fused, plain, strict=True))
