"""``python -m dls_quadruped.bench.mpc_scaling`` end to end on a tiny grid: the JSON's rows, skips, derived numbers,
launch counts and plot (no timing assertions: only that times are positive and ordered as quartiles)."""

from __future__ import annotations

import json

import pytest

from dls_quadruped.bench import mpc_scaling
from dls_quadruped.bench.mpc_warp import problem
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, warm_start
from dls_quadruped.mpc.cpp_kernel import load as load_kernel

pytestmark = pytest.mark.skipif(load_kernel() is None, reason="the C++ kernel cannot be built here")


def test_tiny_grid_rows_skips_and_plot(tmp_path, capsys):
    assert mpc_scaling.main(["--samples", "64", "128", "--robots", "1", "2", "--threads", "1", "2", "--solves", "2",
                             "--max-work", "200", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "mpc_scaling_cpu.json").read_text())
    machine = data["machine"]
    assert machine["kernel"] == "cpp" and machine["device"] == "cpu" and machine["cpu"] and machine["torch"]
    assert len(machine["load_avg_1_5_15"]) == 3 and "200" in machine["skip_rule"]
    rows = {(r["threads"], r["B"], r["M"]): r for r in data["results"]}
    assert set(rows) == {(t, b, m) for t in (1, 2) for b in (1, 2) for m in (64, 128)}
    for t in (1, 2):
        skipped = rows[(t, 2, 128)]  # B M = 256 > 200
        assert "solve_ms" not in skipped and skipped["skipped"] == "B M = 256 > --max-work 200"
        for b, m in ((1, 64), (1, 128), (2, 64)):
            r = rows[(t, b, m)]
            assert 0 < r["solve_q1_ms"] <= r["solve_ms"] <= r["solve_q3_ms"] and r["solves"] >= 3
            assert r["ns_per_rollout"] == pytest.approx(r["solve_ms"] * 1e6 / (b * m)) and r["load_1min"] >= 0
            calls = r["launches"]
            assert calls["kernel_calls"] == 1 and calls["cpp_by_function"]["mpc_solve"] == 1  # the fused solve
            assert calls["cpp_calls"] == sum(calls["cpp_by_function"].values()) > 1
            assert calls["warp_launches"] == 0 and calls["graph_kernels"] is None and calls["torch_ops"] > 0
    printed = capsys.readouterr().out
    assert "| 2 | 128 | skipped |" in printed and "1 kernel, " in printed
    assert (tmp_path / "mpc_scaling_cpu.png").stat().st_size > 10_000
    assert mpc_scaling.main(["--render", str(tmp_path / "mpc_scaling_cpu.json"), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "mpc_scaling.png").stat().st_size > 10_000


def test_budget_skips_the_rest(tmp_path):
    mpc_scaling.main(["--samples", "32", "64", "--robots", "1", "--threads", "1", "--solves", "2",
                      "--budget-s", "1e-9", "--out", str(tmp_path)])
    first, second = json.loads((tmp_path / "mpc_scaling_cpu.json").read_text())["results"]
    assert first["solve_ms"] > 0 and second["skipped"] == "over --budget-s"


@pytest.mark.parametrize("fused", [True, False])
def test_counts_one_kernel_call_per_solve_on_either_path(fused):
    """The fused solve calls ``mpc_solve`` once; the torch path calls ``mpc_costs`` once and no glue function but
    (at most) ``all_finite``; both restore the libraries' functions afterwards."""
    cfg = SamplerConfig(num_samples=64, horizon=5)
    mpc = SamplingMPC(cfg, device="cpu")
    mpc.fused = fused
    state, refs, phase = problem(3, mpc.device)
    default = warm_start.nominal_trot(3, cfg)

    def solve():
        return mpc.solve(state, refs, [mpc.naive_warm_start(default)], phase=phase)

    solve()
    mpc.fused_solve.ready()  # the libraries are loaded on either path
    before = mpc.fused_solve.kernel_lib.mpc_solve
    calls = mpc_scaling.count_launches(mpc, solve)["launches"]
    assert calls["kernel_calls"] == 1
    assert calls["cpp_by_function"].get("mpc_solve" if fused else "mpc_costs") == 1
    if not fused:
        assert set(calls["cpp_by_function"]) <= {"mpc_costs", "all_finite"}
    assert mpc.fused_solve.kernel_lib.mpc_solve is before


def test_bad_device_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        mpc_scaling.main(["--device", "tpu"])
    assert exit_.value.code == 2 and "--device" in capsys.readouterr().err
