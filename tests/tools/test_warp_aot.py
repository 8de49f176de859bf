"""``tools/warp_aot.py``: Warp's CUDA kernels compiled on a machine without a GPU, under the names a GPU's load looks
up. Needs the ``[gpu]`` extra (``make test-gpu-path``); NVRTC ships in Warp's wheel, no GPU or driver is used."""

from __future__ import annotations

import pytest

wp = pytest.importorskip("warp", reason="Warp is not installed (optional [gpu] extra)")
pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")

from dls_quadruped.tools import warp_aot

ARCH = 90


@wp.kernel(module="unique")
def _double(a: wp.array(dtype=float)):
    i = wp.tid()
    a[i] = a[i] * 2.0


@wp.kernel(module="unique")
def _add_one(a: wp.array(dtype=float)):
    i = wp.tid()
    a[i] = a[i] + 1.0


@wp.kernel(module="unique")
def _tiled(a: wp.array2d(dtype=float)):
    i, j = wp.tid()
    a[i, j] = float(j)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """Warp's kernel cache pointed at a fresh folder for the test (restored after it); skips where this Warp's
    NVRTC cannot compile for sm_90."""
    wp.init()
    from warp._src.context import runtime

    if ARCH not in (runtime.nvrtc_supported_archs or ()):
        pytest.skip(f"this Warp's NVRTC cannot compile sm_{ARCH}")
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_a_launch_is_recorded_with_the_block_dim_cuda_would_use():
    """On the CPU every launch runs with blocks of one; the record keeps what the call asked for, which is what a
    CUDA launch uses (256 when it asks for nothing)."""
    a = wp.zeros(4, dtype=float, device="cpu")
    a2 = wp.zeros((2, 8), dtype=float, device="cpu")
    variants: dict = {}
    with warp_aot.record_launches(wp, variants):
        wp.launch(_double, dim=4, inputs=[a], device="cpu")
        wp.launch(_add_one, dim=4, inputs=[a], device="cpu", block_dim=64)
        wp.launch_tiled(_tiled, dim=[2], inputs=[a2], device="cpu", block_dim=32)
    assert set(variants) == {(_double.module.name, 256), (_add_one.module.name, 64), (_tiled.module.name, 32)}
    assert variants[(_tiled.module.name, 32)] is _tiled.module
    assert a.numpy().tolist() == [1.0] * 4  # the launches ran: 0 * 2 + 1
    assert wp.launch.__name__ == "launch" and wp.launch_tiled.__name__ == "launch_tiled"  # the patch is undone


def test_every_module_with_kernels_is_a_variant_at_its_default_block_dim():
    recorded = {(_tiled.module.name, 32): _tiled.module}
    variants = warp_aot.module_variants(wp, recorded)
    assert variants[(_double.module.name, _double.module.options["block_dim"])] is _double.module
    assert (_tiled.module.name, 32) in variants and (_tiled.module.name, 256) in variants


def test_the_compiled_file_is_the_one_warps_own_aot_compile_writes(cache, tmp_path):
    """Cross-check with Warp's public ahead-of-time compile (``wp.compile_aot_module``): same file name, same
    bytes; a second call finds the file and compiles nothing."""
    row = warp_aot.compile_variant(wp, _double.module, _double.module.options["block_dim"], ARCH, "cubin")
    assert "error" not in row and row["compiled"] is True
    ours = cache / row["file"]
    assert ours.name.endswith(f".sm{ARCH}.cubin") and ours.stat().st_size == row["bytes"] > 0
    theirs = wp.compile_aot_module(_double.module, arch=ARCH, module_dir=tmp_path / "aot")
    assert [p.name for p in map(type(ours), theirs)] == [ours.name]
    assert ours.parent.name == _double.module.get_module_identifier(_double.module.options["block_dim"])
    assert type(ours)(theirs[0]).read_bytes() == ours.read_bytes()
    again = warp_aot.compile_variant(wp, _double.module, _double.module.options["block_dim"], ARCH, "cubin")
    assert again["compiled"] is False and again["file"] == row["file"]


def test_a_block_dim_variant_has_its_own_hash_and_file(cache):
    default, other = _add_one.module.options["block_dim"], 64
    assert default != other
    rows = [warp_aot.compile_variant(wp, _add_one.module, bd, ARCH, fmt)
            for bd, fmt in ((default, "cubin"), (other, "cubin"), (other, "ptx"))]
    assert all("error" not in r for r in rows), rows
    files = [cache / r["file"] for r in rows]
    assert files[0].parent != files[1].parent == files[2].parent
    assert files[1].parent.name == _add_one.module.get_module_identifier(other)
    assert files[2].name == files[1].name.replace(".cubin", ".ptx")
    assert files[2].read_text().lstrip().startswith("//")  # PTX is text, led by its generator's comments


def test_a_failed_compile_is_reported_in_its_row_and_the_others_go_on(cache):
    row = warp_aot.compile_variant(wp, _double.module, 256, 11, "cubin")  # sm_11 exists in no toolkit
    assert set(row) == {"module", "block_dim", "error", "seconds"} and row["error"]


@pytest.mark.parametrize("argv, needles", [
    (["--tasks", "bogus"], ("unknown ones ['bogus']", "allowed: ", "rough")),
    (["--tasks", ","], ("names no task", "allowed: ")),
    (["--arch", "11"], ("cannot compile for sm_11", "it can: [", "90")),
])
def test_bad_arguments_are_one_line_errors(one_line_error, tmp_path, argv, needles):
    line = one_line_error(warp_aot.main, ["--cache", str(tmp_path / "c"), *argv])
    assert all(n in line for n in needles), line
    assert not (tmp_path / "c").exists()  # refused before anything is written


@pytest.mark.slow
def test_a_dry_run_of_base_defines_mujoco_warps_tiled_kernels_at_their_cuda_block_dims():
    """base on warp-cpu, 2 robots, 8 steps with resets: MuJoCo Warp's tiled launches are recorded at the widths of
    its ``BlockDim`` table, which a CPU run never uses."""
    import dataclasses

    from mujoco_warp._src.types import BlockDim

    recorded: dict = {}
    resets = warp_aot.define_task_kernels(wp, ["base"], 2, 8, recorded)
    assert resets["base"] > 0
    widths = {f.default for f in dataclasses.fields(BlockDim)}
    tiled = {bd for (_, bd) in recorded if bd != warp_aot.CUDA_DEFAULT_BLOCK_DIM}
    assert tiled and tiled <= widths, (tiled, widths)
    variants = warp_aot.module_variants(wp, recorded)
    assert set(recorded) <= set(variants)
    defaults = {(name, bd) for name, bd in variants if (name, bd) not in recorded}
    assert all(bd == variants[(name, bd)].options["block_dim"] for name, bd in defaults)
