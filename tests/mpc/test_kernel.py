"""Fast (fused) and C++ kernels == reference kernel; C++ build fallback; counter-based noise statistics."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc import cpp_kernel, kernel, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.kernel import (
    KernelInputs,
    cpp_costs,
    fast_costs,
    reference_costs,
)
from dls_quadruped.mpc.rng import normals
from dls_quadruped.mpc.samples import group_layout
from dls_quadruped.mpc.srbd import robot_srbd_model


def _inputs(standing, cfg: SamplerConfig, seed: int = 7) -> KernelInputs:
    gen = torch.Generator().manual_seed(seed)
    state, refs = standing(2)
    x0 = state.as_vector()
    x0[:, 3:12] += 0.2 * torch.randn(2, 9, generator=gen)  # moving, tilted, rotating
    ws0 = warm_start.nominal_trot(2, cfg)
    ws1 = ws0 + 0.5 * torch.randn(ws0.shape, generator=gen) * (ws0.abs() + 1.0)  # something else entirely
    group, perturb, _ = group_layout(cfg.num_samples, (0.3, 0.7))
    return KernelInputs(
        seed=torch.tensor(1234), warm_starts=torch.stack([ws0, ws1], dim=1), group=group, perturb=perturb, x0=x0,
        phase=torch.tensor([[0.1, 0.6, 0.6, 0.1], [0.45, 0.95, 0.95, 0.45]]),
        base_xy_w=torch.tensor([[0.0, 0.0], [0.3, -0.1]]),
        base_yaw=torch.tensor([0.0, 0.7]), terrain_z_w=torch.tensor([[0.0] * 4, [0.05, 0.05, -0.02, 0.0]]), refs=refs,
    )


def _assert_costs_match(fast: torch.Tensor, ref: torch.Tensor) -> None:
    finite = torch.isfinite(ref)
    assert torch.equal(finite, torch.isfinite(fast))
    rel = ((fast - ref).abs() / ref.abs().clamp_min(1.0))[finite]
    # float32 with a different summation order; a contact flag sitting exactly on a phase boundary
    # may flip between the two, so allow a handful of outliers but require agreement elsewhere.
    assert (rel > 1e-4).float().mean() < 0.002, rel.max()
    assert torch.median(rel) < 1e-5


@pytest.mark.parametrize("enc_p,enc_F", [("first", "spline"), ("discrete", "discrete"), ("spline", "first")])
def test_fused_eager_matches_reference(enc_p, enc_F, standing):
    cfg = SamplerConfig(num_samples=300, horizon=5, encoding_p=enc_p, encoding_F=enc_F)
    inp = _inputs(standing, cfg)
    model = robot_srbd_model()
    ref = reference_costs(inp, cfg, model)
    assert ref.shape == (2, 300) and torch.isfinite(ref).all()
    _assert_costs_match(fast_costs(inp, cfg, model, compiled=False), ref)


def test_fused_eager_matches_reference_sigma_off(standing):
    cfg = SamplerConfig(num_samples=200, horizon=6, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    inp = _inputs(standing, cfg, seed=3)
    model = robot_srbd_model()
    _assert_costs_match(fast_costs(inp, cfg, model, compiled=False), reference_costs(inp, cfg, model))


@pytest.mark.slow
def test_compiled_matches_reference(standing):
    """torch.compile'd kernel (minutes to compile cold on 2 cores; cached afterwards)."""
    cfg = SamplerConfig(num_samples=2000, horizon=10)
    inp = _inputs(standing, cfg, seed=11)
    model = robot_srbd_model()
    _assert_costs_match(fast_costs(inp, cfg, model, compiled=True), reference_costs(inp, cfg, model))


@pytest.fixture(scope="module")
def cpp_lib():
    lib = cpp_kernel.load()  # ~1 s cold build, cached afterwards
    if lib is None:
        pytest.skip("no working C++ compiler: the cpp kernel falls back to fast (tested below)")
    return lib


@pytest.mark.parametrize("enc_p,enc_F,horizon", [("first", "spline", 10), ("discrete", "discrete", 5),
                                                 ("spline", "first", 7)])
def test_cpp_matches_reference(cpp_lib, enc_p, enc_F, horizon, standing):
    cfg = SamplerConfig(num_samples=300, horizon=horizon, encoding_p=enc_p, encoding_F=enc_F)  # 300 = 18 x 16 + 12
    inp = _inputs(standing, cfg)
    model = robot_srbd_model()
    ref = reference_costs(inp, cfg, model)
    assert torch.isfinite(ref).all()
    _assert_costs_match(cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib), ref)


def test_cpp_sigma_off_threads_and_nan(cpp_lib, standing):
    cfg = SamplerConfig(num_samples=200, horizon=6, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    inp = _inputs(standing, cfg, seed=3)
    model = robot_srbd_model()
    ref = reference_costs(inp, cfg, model)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = cpp_costs(inp, cfg, model)
        torch.set_num_threads(2)
        two = cpp_costs(inp, cfg, model)
    finally:
        torch.set_num_threads(threads)
    _assert_costs_match(one, ref)
    assert torch.equal(one, two)  # per-sample maths: the thread count changes no number
    inp.x0[1, 7] = float("nan")  # robot 1 diverges: every sample +inf, robot 0 untouched
    nan_costs = cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib)
    assert torch.isposinf(nan_costs[1]).all() and torch.isposinf(reference_costs(inp, cfg, model)[1]).all()
    assert torch.equal(nan_costs[0], one[0])


def test_cpp_build_failure_warns_and_falls_back(monkeypatch, tmp_path, standing):
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    cpp_kernel.load.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="falling back to the 'fast' kernel"):
            assert cpp_kernel.load() is None
        calls = []
        monkeypatch.setattr(kernel, "fast_costs", lambda inp, cfg, model: calls.append(cfg) or torch.zeros(2, 3))
        cfg = SamplerConfig(num_samples=3, horizon=5)
        assert torch.equal(kernel.cpp_costs(_inputs(standing, cfg), cfg, robot_srbd_model()), torch.zeros(2, 3))
        assert calls == [cfg]
    finally:
        cpp_kernel.load.cache_clear()


def test_cpp_build_fallback_says_which_flags_and_cache_keys_host(cpp_lib, monkeypatch, tmp_path, capsys, standing):
    """-march=native rejected -> the next flag set (here without OpenMP) builds, says so once per process, and
    computes the same costs; a library built on another CPU is not reused."""
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    monkeypatch.setattr(cpp_kernel, "FLAG_SETS",
                        (["-O1", "-march=no-such-cpu", "-fopenmp"], ["-O1", "-fno-math-errno"]))
    cpp_kernel.load.cache_clear()
    try:
        lib = cpp_kernel.load()
        assert lib is not None and cpp_kernel.load() is lib
        err = capsys.readouterr().err
        assert err.count("did not build with '-O1 -march=no-such-cpu -fopenmp'; built with '-O1 -fno-math-errno'") == 1
        cfg = SamplerConfig(num_samples=100, horizon=5)
        inp = _inputs(standing, cfg)
        model = robot_srbd_model()
        _assert_costs_match(cpp_kernel.cpp_costs(inp, cfg, model, lib), cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib))
        cpp_kernel.load.cache_clear()  # as in a new process: the cached library is reused and says so again
        assert cpp_kernel.load() is not None and "built with '-O1 -fno-math-errno'" in capsys.readouterr().err
        assert len(list(cpp_kernel.build_dir().glob("*.so"))) == 1
        monkeypatch.setattr(cpp_kernel, "_host_signature", lambda: "x86_64|another CPU|sse2")
        cpp_kernel.load.cache_clear()
        assert cpp_kernel.load() is not None
        assert len(list(cpp_kernel.build_dir().glob("*.so"))) == 2
    finally:
        cpp_kernel.load.cache_clear()


def test_cpp_unknown_variant_names_the_allowed_ones():
    with pytest.raises(ValueError, match="unknown C\\+\\+ kernel variant 'avx9'; allowed: native, x86-64-v3, scalar"):
        cpp_kernel.flag_sets("avx9")


def test_counter_normals_statistics_and_determinism():
    counter0 = torch.arange(20000, dtype=torch.int64) * 4
    z = normals(torch.tensor(5), counter0, 8)  # (20000, 8)
    assert z.shape == (20000, 8)
    assert abs(z.mean().item()) < 0.01 and abs(z.std().item() - 1.0) < 0.01
    assert abs((z**4).mean().item() - 3.0) < 0.1  # Gaussian kurtosis
    corr = torch.corrcoef(z.T)
    assert (corr - torch.eye(8)).abs().max() < 0.03  # entries (incl. the cos/sin pair) uncorrelated
    assert torch.equal(z, normals(torch.tensor(5), counter0, 8))
    assert (z - normals(torch.tensor(6), counter0, 8)).abs().mean() > 0.5  # another seed, other numbers
    assert ((z[:, :4] - z[:, 4:]).abs() > 0).all()  # overlapping counters would repeat values
