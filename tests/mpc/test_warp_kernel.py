"""The ``warp`` kernel (mpc/warp_kernel.py) on Warp's CPU device against the ``cpp`` kernel and the reference kernel.

Same problems as the cpp kernel's tests (tests/mpc/test_kernel.py: three encodings, two warm-start groups 30/70 around
a trot and something else entirely, moving tilted robots, another frame and terrain; test_solve_glue.py's
spline-spline and its layouts 70/30 and 50/50), plus one warm start alone and B = 16 perturbed robots per problem:
costs within 1e-5 relative of the cpp kernel's, and the device argmin picks the cpp kernel's winner in >= 99 % of
the robots. First run: ~3 s of Warp compile per sample-vector bucket, cached in ~/.cache/warp afterwards.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc import cpp_kernel, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.kernel import KernelInputs, reference_costs
from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY
from dls_quadruped.mpc.samples import group_layout
from dls_quadruped.mpc.srbd import robot_srbd_model

wp = pytest.importorskip("warp")
warp_kernel = pytest.importorskip("dls_quadruped.mpc.warp_kernel")
warp_argmin = pytest.importorskip("dls_quadruped.mpc.warp_argmin")

ENCODINGS = [("first", "spline", 10), ("discrete", "discrete", 5), ("spline", "first", 7), ("spline", "spline", 10)]
LAYOUTS = [(1.0,), (0.3, 0.7), (0.7, 0.3), (0.5, 0.5)]


@pytest.fixture(scope="module")
def cpp_lib():
    lib = cpp_kernel.load()
    if lib is None:
        pytest.skip("no C++ compiler: nothing to compare the warp kernel with")
    return lib


def _inputs(perturbed_standing, cfg: SamplerConfig, props: tuple[float, ...], b: int = 16,
            seed: int = 7) -> KernelInputs:
    """B perturbed robots (moving, tilted, rotating), warm start 0 a trot, warm start 1 something else entirely,
    another frame and terrain per robot, noise seed 1234 (tests/mpc/test_kernel.py's problem, B robots)."""
    gen = torch.Generator().manual_seed(seed)
    state, refs, phase = perturbed_standing(b, seed)
    x0 = state.as_vector()
    x0[:, 3:12] += 0.2 * torch.randn(b, 9, generator=gen)
    ws0 = warm_start.nominal_trot(b, cfg)
    ws1 = ws0 + 0.5 * torch.randn(ws0.shape, generator=gen) * (ws0.abs() + 1.0)
    group, perturb, _ = group_layout(cfg.num_samples, props)
    return KernelInputs(
        seed=torch.tensor(1234), warm_starts=torch.stack([ws0, ws1][:len(props)], dim=1), group=group,
        perturb=perturb, x0=x0, phase=phase, base_xy_w=0.3 * torch.randn(b, 2, generator=gen),
        base_yaw=torch.randn(b, generator=gen), terrain_z_w=0.05 * torch.randn(b, 4, generator=gen), refs=refs)


def _assert_agree(warp_costs: torch.Tensor, cpp_costs: torch.Tensor) -> None:
    finite = torch.isfinite(cpp_costs)
    assert torch.equal(finite, torch.isfinite(warp_costs))
    rel = ((warp_costs - cpp_costs).abs() / cpp_costs.abs())[finite]
    assert rel.max() < 1e-5, rel.max()


@pytest.mark.parametrize("enc_p,enc_F,horizon", ENCODINGS)
@pytest.mark.parametrize("props", LAYOUTS)
def test_warp_costs_and_argmin_agree_with_cpp(cpp_lib, enc_p, enc_F, horizon, props, perturbed_standing):
    cfg = SamplerConfig(num_samples=300, horizon=horizon, encoding_p=enc_p, encoding_F=enc_F)  # 300 = 18 x 16 + 12
    inp = _inputs(perturbed_standing, cfg, props)
    model = robot_srbd_model()
    cpp = cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib)
    costs = KERNEL_REGISTRY.get("warp")(inp, cfg, model)
    assert costs.shape == (16, 300) and torch.isfinite(cpp).all()
    _assert_agree(costs, cpp)
    best_cost, best_index = warp_argmin.warp_argmin(costs)
    cpp_best, cpp_index = cpp.min(dim=1)  # the cpp kernel's mpc_solve: the first minimum of each row
    assert (best_index == cpp_index).float().mean() >= 0.99
    assert torch.equal(best_cost, costs.gather(1, best_index[:, None])[:, 0])
    torch.testing.assert_close(best_cost, cpp_best, rtol=1e-5, atol=0.0)


def test_argmin_over_many_problems_and_a_large_m(cpp_lib, perturbed_standing):
    """64 robots x M = 5 000 (T = 256 partial scans of ~20 samples each): winners identical in >= 99 % of the
    robots, and the cpp kernel's fused mpc_solve argmin agrees with torch.min (what the comparison uses)."""
    cfg = SamplerConfig(num_samples=5000, horizon=10)
    inp = _inputs(perturbed_standing, cfg, (0.5, 0.5), b=64, seed=3)
    model = robot_srbd_model()
    cpp = cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib)
    costs = warp_kernel.warp_costs(inp, cfg, model)
    _assert_agree(costs, cpp)
    _, index = warp_argmin.warp_argmin(costs)
    assert (index == cpp.min(dim=1).indices).float().mean() >= 0.99


def test_argmin_ties_go_to_the_lowest_index():
    """Hand-made rows: ties inside one level-1 thread, across threads (the last stage's tie rule), across levels of a
    3-level tree, all +inf, a single sample and M <= 32 (no level): the first minimum, as torch.min and the cpp
    kernel's strict '<' scan."""
    m = 600  # plan: 19 level-1 threads (thread t: samples t, t + 19, ...), then the last stage scans 19
    assert warp_argmin.plan(m) == (19,) and warp_argmin.plan(40000) == (1250, 40, 2) and warp_argmin.plan(32) == ()
    rows = torch.full((5, m), 5.0)
    rows[0, [41, 22, 3]] = 1.0  # one thread (3 mod 19), three ties -> 3
    rows[1, [300, 44]] = 1.0  # threads 15 and 6 -> 44
    rows[2, [599, 2]] = 0.5  # -> 2
    rows[3] = float("inf")  # every sample diverged -> 0
    rows[4, 1:] = torch.arange(1, m, dtype=torch.float32)  # minimum at index 1 (row 4, sample 0 stays 5)
    best_cost, best_index = warp_argmin.warp_argmin(rows)
    expected = torch.min(rows, dim=1)
    assert best_index.tolist() == [3, 44, 2, 0, 1] == expected.indices.tolist()
    assert torch.equal(best_cost, expected.values)
    big = torch.full((3, 40000), 2.0)
    big[0, [39999, 31250, 17]] = -1.0  # ties in different level-1, level-2 and level-3 groups -> 17
    big[1, 39999] = 0.0  # the last sample alone
    big[2, [1250 * 7 + 3, 3]] = 0.0  # level-1 thread 3 twice -> 3
    assert warp_argmin.warp_argmin(big)[1].tolist() == [17, 39999, 3] == torch.min(big, dim=1).indices.tolist()
    single = warp_argmin.warp_argmin(torch.tensor([[3.0], [float("inf")]]))
    assert single[1].tolist() == [0, 0]
    small = torch.tensor([[2.0, 1.0, 1.0, 4.0]])
    assert warp_argmin.warp_argmin(small)[1].tolist() == [1]


def test_warp_matches_reference_sigma_off_and_nan_state(cpp_lib, standing):
    """The cpp tests' sigma-off problem: both kernels against the eager reference, and a NaN state -> every sample
    of that robot +inf while the other robot's costs do not change."""
    cfg = SamplerConfig(num_samples=200, horizon=6, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    state, refs = standing(2)
    gen = torch.Generator().manual_seed(3)
    x0 = state.as_vector()
    x0[:, 3:12] += 0.2 * torch.randn(2, 9, generator=gen)
    group, perturb, _ = group_layout(cfg.num_samples, (1.0,))
    inp = KernelInputs(torch.tensor(99), warm_start.nominal_trot(2, cfg)[:, None], group, perturb, x0,
                       torch.tensor([[0.1, 0.6, 0.6, 0.1], [0.45, 0.95, 0.95, 0.45]]), torch.zeros(2, 2),
                       torch.tensor([0.0, 0.7]), torch.zeros(2, 4), refs)
    model = robot_srbd_model()
    ref = reference_costs(inp, cfg, model)
    costs = warp_kernel.warp_costs(inp, cfg, model)
    rel = (costs - ref).abs() / ref.abs().clamp_min(1.0)
    assert torch.median(rel) < 1e-5 and (rel > 1e-4).float().mean() < 0.002
    _assert_agree(costs, cpp_kernel.cpp_costs(inp, cfg, model, cpp_lib))
    inp.x0[1, 7] = float("nan")
    nan_costs = warp_kernel.warp_costs(inp, cfg, model)
    assert torch.isposinf(nan_costs[1]).all() and torch.equal(nan_costs[0], costs[0])


def test_counter_hash_and_normals_match_the_torch_draws():
    """The kernel's own hash, log and sincos give rng.normals' numbers (torch's log, cos, sin) for the rollout's
    counters (b M + m) D / 2 + j / 2, within float32 round-off."""
    from dls_quadruped.mpc.rng import normals

    seed, b, m, dim = torch.tensor(2024), 3, 64, 88
    counters = (torch.arange(b)[:, None] * m + torch.arange(m)[None, :]) * (dim // 2)
    expected = normals(seed, counters, dim)  # (B, M, D)
    got = _draws(seed, b, m, dim)
    assert got.shape == expected.shape == (b, m, dim)
    torch.testing.assert_close(got, expected, rtol=2e-6, atol=2e-6)
    assert not torch.equal(got, _draws(seed + 1, b, m, dim))


def _draws(seed: torch.Tensor, b: int, m: int, dim: int) -> torch.Tensor:
    """(B, M, D) normals drawn by warp_math.normal_pair with the rollout's counters."""
    from dls_quadruped.mpc.warp_math import normal_pair, seed_key

    @wp.kernel(enable_backward=False)
    def draw(m_total: int, dim: int, seed: wp.array(dtype=wp.int64), out: wp.array(dtype=wp.float32)):
        i, j = wp.tid()
        key = seed_key(seed[0])
        z = normal_pair(wp.uint32(i) * wp.uint32(dim // 2) + wp.uint32(j), key)
        out[i * dim + 2 * j] = z[0]
        out[i * dim + 2 * j + 1] = z[1]

    warp_kernel.init()
    out = torch.empty(b * m * dim)
    wp.launch(draw, dim=(b * m, dim // 2), inputs=[m, dim, wp.from_torch(seed.reshape(1)), wp.from_torch(out)],
              device="cpu")
    return out.view(b, m, dim)


def test_a_too_long_sample_is_refused_with_the_limit():
    with pytest.raises(ValueError, match="at most 512 encoded entries per sample, got D = 600"):
        warp_kernel.bucket(600)
    assert [warp_kernel.bucket(d) for d in (28, 64, 65, 308)] == [64, 64, 128, 512]


def test_cuda_code_compiles_for_hopper(tmp_path):
    """The CUDA path without a GPU: Warp generates each module's CUDA code and NVRTC compiles it for sm_90 (H100/H200)
    -- the native bit casts, the uint32 hash, the int64 indices. Skipped where Warp has no NVRTC."""
    from dls_quadruped.mpc import warp_argmin, warp_decode

    warp_kernel.init()
    runtime = getattr(getattr(wp, "_src", None), "context", None)
    archs = getattr(getattr(runtime, "runtime", None), "nvrtc_supported_archs", None) or ()
    if 90 not in archs:
        pytest.skip("Warp without NVRTC for sm_90 here: the CUDA code is not compiled")
    modules = [warp_kernel.rollout_kernel(64).module, warp_decode.decode_kernel(64).module,
               warp_decode.clean_kernel.module, warp_argmin.argmin_reduce.module]
    for module in modules:
        (ptx,) = wp.compile_aot_module(module, arch=90, module_dir=tmp_path, use_ptx=True)
        assert ptx.suffix == ".ptx" and ".entry" in ptx.read_text()
