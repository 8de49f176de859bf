"""The chapter-7.3 experiment scripts (Tables 14-17) end to end on a tiny cell: table files, the per-cell
cache that lets an interrupted script continue, and a missing student reported as skipped."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _run(module: str, out: Path, *extra: str) -> str:
    """``python -m experiments.<module> ...`` from the repository root, as the docs run it."""
    cmd = [sys.executable, "-m", f"experiments.{module}", "--episodes", "2", "--seconds", "0.2",
           "--num-workers", "0", "--out", str(out), *extra]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_table16_cell_is_cached_and_tabulated(tmp_path: Path) -> None:
    out = tmp_path / "t16"
    _run("table16_samples", out, "--only", "naive_warm_start_M4000")
    cell = out / "cells" / "naive_warm_start_M4000.json"
    summary = json.loads(cell.read_text())
    assert summary["episodes"] == 2 and summary["sampler"] == {"num_samples": 4000}
    assert summary["rollout_cost"]["n"] > 0 and len(summary["horizon_cost"]) == 10
    table = (out / "table.md").read_text()
    assert "| naive_warm_start | 4000 |" in table and "33.82" in table  # ours beside the thesis's initial cost
    stamp = cell.stat().st_mtime_ns
    _run("table16_samples", out, "--only", "naive_warm_start_M4000")  # resumes: nothing to recompute
    assert cell.stat().st_mtime_ns == stamp


def test_missing_student_is_skipped_not_replaced(tmp_path: Path) -> None:
    out = tmp_path / "t15"
    stdout = _run("table15_horizon", out, "--students", str(tmp_path / "none"), "--single-student", "--only",
                  "rl_warm_start_dt0.04_H5")
    assert "skipped" in stdout
    results = json.loads((out / "results.json").read_text())
    assert "no student first-spline_H5_dt0.04" in results["rl_warm_start_dt0.04_H5"]["skipped"]
    assert not (out / "cells" / "rl_warm_start_dt0.04_H5.json").exists()


def test_training_seeds_merge_per_episode_means() -> None:
    """A Table 15 row from two students' cells: per episode, each student's mean over its sampler seeds;
    survival pooled; the median over (student, episode) values."""
    from experiments.warm_start_seeds import merge_training_seeds

    def cell(name, reward, survived):  # (S = 2 sampler seeds, E = 3 episodes)
        return {"cell": name, "controller": "rl_warm_start", "episodes": 3, "replicas": 2,
                "survival": {"rate": sum(map(sum, survived)) / 6},
                "per_episode": {"rl_reward": reward, "survived": survived},
                "rl_reward": {"median": 0.0}, "horizon_cost": [{"median": 1.0}, {"median": 4.0}]}

    a = cell("s0", [[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]], [[1, 1, 1], [1, 0, 1]])  # per episode: 2, 3, 4
    b = cell("s1", [[10.0, 0.0, 6.0], [12.0, 2.0, 8.0]], [[1, 1, 1], [1, 1, 1]])  # per episode: 11, 1, 7
    b["horizon_cost"] = [{"median": 3.0}, {"median": 8.0}]
    m = merge_training_seeds([a, b])
    assert m["per_episode"]["rl_reward"] == [[2.0, 3.0, 4.0], [11.0, 1.0, 7.0]]
    assert m["rl_reward"]["median"] == 3.5  # median of 1, 2, 3, 4, 7, 11
    assert m["survival"]["rate"] == (5 / 6 + 1) / 2 and m["episodes"] == 3 and m["training_seeds"] == 2
    assert [h["median"] for h in m["horizon_cost"]] == [2.0, 6.0]
    assert merge_training_seeds([a, {"skipped": "no student x"}]) == {"skipped": "no student x"}


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_table18_two_students_and_the_policies_alone(tmp_path: Path) -> None:
    """Table 18's two-policy cell (the base student under two names) beside both policies alone: paired
    differences from each, the groups' wins, switches per second and robot 0's winner trace (Fig. 34)."""
    pol = tmp_path / "policies"
    pol.mkdir()
    src = REPO / "docs" / "policies"
    for name in ("base_actor.pt", "speed_actor.pt", "base_student_first_spline_h10.pt"):
        (pol / name).symlink_to(src / name)
    (pol / "speed_student_first_spline_h10.pt").symlink_to(src / "base_student_first_spline_h10.pt")
    out = tmp_path / "t18"
    _run("table18_multi_policy", out, "--policy-dir", str(pol), "--sampler-seeds", "1",
         "--only", "ws_base+speed", "alone_base", "alone_speed", "ws_rough")
    cell = json.loads((out / "cells" / "ws_base+speed.json").read_text())
    assert len(cell["student"]) == 2 and set(cell["warm_start_won"]) <= {"0", "1"}
    assert len(cell["winner_trace_robot0"]) == 2 * 10  # 0.2 s: 10 policy steps x 2 solves
    assert cell["rl_return"]["n"] == 2 and "winner_switches_per_s" in cell["per_episode"]
    table = (out / "table.md").read_text()
    assert "vs base:" in table and "vs speed:" in table
    assert "skipped: no student" in table  # rough's student is not there


@pytest.mark.slow
def test_table18_stairs_part_blind_vs_aware(tmp_path: Path) -> None:
    """``--stairs`` (issue 27 item 6): base's and the naive warm start, blind and aware, and base alone on the
    stairs; an explicit --seconds overrides the stairs cells' 15 s; per height success, survival and climbed
    fraction, and the paired aware - blind differences (~25 s)."""
    out = tmp_path / "t18s"
    _run("table18_multi_policy", out, "--stairs", "--sampler-seeds", "1")
    names = {p.stem for p in (out / "cells").glob("*.json")}
    assert names == {"ws_base_stairs_blind", "ws_base_stairs_aware", "naive_stairs_blind", "naive_stairs_aware",
                     "alone_base_stairs"}
    cell = json.loads((out / "cells" / "naive_stairs_aware.json").read_text())
    assert cell["ground"] == "terrain" and cell["scenario"] == "stairs" and cell["seconds"] == 0.2
    assert [r["step_height"] for r in cell["stairs"]["per_height"]] == [0.05, 0.1, 0.15, 0.2]
    assert cell["episodes"] == 2 * 4  # --episodes per height
    table = (out / "stairs.md").read_text()
    assert table.count("naive, aware |") == 5 and "Δ success aware - blind" in table
    assert (out / "stairs.png").is_file() and not (out / "table.md").exists()


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_shards_split_the_cells_and_the_run_without_shard_tabulates_them(tmp_path: Path) -> None:
    out = tmp_path / "t16"
    first, second = "naive_warm_start_M10000", "naive_warm_start_M4000"  # positions 4 and 3 of table16's cells
    stdout = _run("table16_samples", out, "--only", first, second, "--shard", "1/2")
    assert sorted(p.name for p in (out / "cells").iterdir()) == [f"{second}.json"]  # position 3: 3 % 2 == 1
    assert "run once more without --shard" in stdout and not (out / "table.md").exists()
    stamp = (out / "cells" / f"{second}.json").stat().st_mtime_ns
    _run("table16_samples", out, "--only", first, second)  # runs the other shard's cell, reuses this one
    assert (out / "cells" / f"{first}.json").is_file() and (out / "table.md").is_file()
    assert (out / "cells" / f"{second}.json").stat().st_mtime_ns == stamp


@pytest.mark.parametrize("bad", ["2/2", "1", "a/b", "0/0"])
def test_bad_shard_is_a_one_line_usage_error(tmp_path: Path, bad: str) -> None:
    cmd = [sys.executable, "-m", "experiments.table16_samples", "--out", str(tmp_path), "--shard", bad]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 2 and "--shard" in res.stderr and "K/N" in res.stderr
    assert not (tmp_path / "cells").exists()


def test_table15_shards_refuse_to_distil_students_side_by_side(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "experiments.table15_horizon", "--out", str(tmp_path / "t15"),
           "--students", str(tmp_path / "none"), "--only", "rl_warm_start_dt0.04_H5_seed0", "--shard", "0/2"]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 2 and "--students-only" in res.stderr and "(0.04, 5)" in res.stderr
    assert not (tmp_path / "none").exists()  # nothing distilled


def test_rugged_clearance_help_and_bad_difficulty() -> None:
    script = ["-m", "experiments.rugged_clearance"]
    ok = subprocess.run([sys.executable, *script, "--help"], cwd=REPO, capture_output=True, text=True, timeout=120,
                        check=False)
    assert ok.returncode == 0 and "--difficulty" in ok.stdout
    bad = subprocess.run([sys.executable, *script, "--difficulty", "1.5"], cwd=REPO, capture_output=True, text=True,
                         timeout=120, check=False)
    assert bad.returncode == 2 and "each must be in [0, 1], got [1.5]" in bad.stderr


@pytest.mark.slow  # ~30 s; the gait itself is tested fast in tests/closed_loop/test_closed_loop.py
def test_naive_gait_sweep_runs_a_cell_at_its_gait(tmp_path: Path) -> None:
    """Issue 38 item 6's script: one cell of the grid at 1.5 m/s, its gait recorded and tabulated."""
    out = tmp_path / "gait"
    _run("naive_gait_sweep", out, "--only", "naive_f2.5_d0.5")
    cell = json.loads((out / "cells" / "naive_f2.5_d0.5.json").read_text())
    assert cell["naive_gait"] == [2.5, 0.5] and cell["episodes"] == 2
    assert "| 2.5 | 0.5 |" in (out / "table.md").read_text()


def test_naive_gait_sweep_help_and_bad_scale() -> None:
    script = ["-m", "experiments.naive_gait_sweep"]
    ok = subprocess.run([sys.executable, *script, "--help"], cwd=REPO, capture_output=True, text=True, timeout=120,
                        check=False)
    assert ok.returncode == 0 and "gait" in ok.stdout and "--shard" in ok.stdout
    bad = subprocess.run([sys.executable, *script, "--scale", "huge"], cwd=REPO, capture_output=True, text=True,
                         timeout=120, check=False)
    assert bad.returncode == 2 and "invalid choice: 'huge'" in bad.stderr


def test_com_height_applies_to_mpc_cells_and_a_cache_of_another_height_is_refused(tmp_path: Path) -> None:
    """``--com-height`` is the reference of every cell without its own (the MPC's and every controller's initial
    cost); a cached cell run with another reference is not reused silently."""
    import argparse

    from experiments.warm_start_common import Cell, cell_com_height, run_cells

    args = argparse.Namespace(com_height=0.40, out=tmp_path, only=None, threads=1)
    assert cell_com_height(Cell("a", "rl_warm_start"), args) == 0.40
    assert cell_com_height(Cell("b", "naive_warm_start"), args) == 0.40
    assert cell_com_height(Cell("c", "naive_warm_start", com_height=0.30), args) == 0.30  # the cell's own wins
    assert cell_com_height(Cell("d", "rl_baseline"), args) == 0.40  # its initial cost is scored at that height
    assert cell_com_height(Cell("a", "rl_warm_start"), argparse.Namespace()) is None  # scripts without the flag
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / "a.json").write_text(json.dumps({"cell": "a", "com_height": None}))
    with pytest.raises(SystemExit, match="CoM height reference None.*asks for 0.4: use another --out"):
        run_cells([Cell("a", "rl_warm_start")], args)
    args.com_height = None
    assert run_cells([Cell("a", "rl_warm_start")], args)["a"]["com_height"] is None  # same height: the cache


def test_com_height_out_of_range_is_a_usage_error() -> None:
    bad = subprocess.run([sys.executable, "-m", "experiments.table14_warm_start_encodings",
                          "--com-height", "0.9"], cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "--com-height must be in [0.1, 0.6] m, got 0.9" in bad.stderr
