"""The chapter-7.3 experiment scripts (Tables 14-17) end to end on a tiny cell: table files, the per-cell
cache that lets an interrupted script continue, and a missing student reported as skipped."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
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


def _cell_summary(controller: str, per_episode: dict, replicas: int, com_height=None) -> dict:
    """A cached cell as ``run_cells`` writes it, from (S, E) per-episode values (what ``summarize`` keeps)."""
    from dls_quadruped.eval.metrics import episode_summary

    e = len(per_episode["survived"][0])
    rate = float(np.mean(per_episode["survived"]))
    out = {"controller": controller, "episodes": e, "replicas": replicas, "com_height": com_height,
           "survival": {"rate": rate, "ci95": [rate, rate], "n": e * replicas},
           "per_episode": {k: np.asarray(v).tolist() for k, v in per_episode.items()}}
    for k, v in per_episode.items():
        if k != "survived":
            out[k] = episode_summary(np.asarray(v, dtype=float))
    return out


@pytest.mark.slow  # ~30 s of bootstraps (120 paired differences)
def test_cost_gap_merges_three_students_and_splits_the_gap_by_term(tmp_path: Path, monkeypatch) -> None:
    """cost_gap.py on cached cells built by hand: students k = 0, 1, 2 exceed the naive warm start's
    height term by 10 (k + 1) on every episode and match it elsewhere, so the merged RL - naive height term is
    +20 (each student's own: +10, +20, +30, with zero-width intervals); the merged interval resamples the
    students, and 3 draws of student 0 (or of student 2) have probability 1/27 > 2.5 %, so it is [+10, +30] by
    hand; the other terms are 0 and the total's mean gap equals the height term's. The state rollout cost's
    v_x term likewise: students exceed naive's by 5 (k + 1), so +10 [+5, +15]."""
    from dls_quadruped.mpc.cost import STATE_TERMS
    from experiments import cost_gap

    rng = np.random.default_rng(0)
    e, s = 6, 2
    students, out = tmp_path / "students", tmp_path / "gap"
    (out / "cells").mkdir(parents=True)
    for p, F in cost_gap.ENCODINGS:
        enc = f"{p}-{F}"
        # the same values for every sampler seed: paired_difference resamples the seeds of two cells independently
        base = {f"{kind}_term_{t}": np.repeat(rng.uniform(1, 5, (1, e)), s, axis=0)
                for t in STATE_TERMS for kind in ("initial", "rollout")}
        common = {"rl_reward": rng.uniform(2, 2.3, (s, e)), "rl_return": rng.uniform(1000, 1700, (s, e)),
                  "initial_cost": rng.uniform(20, 60, (s, e)), "rollout_cost": rng.uniform(100, 300, (s, e)),
                  "survived": np.ones((s, e))}

        def write(name, terms, controller, common=common):
            pe = {**common, **terms, "initial_cost_mean": sum(v for k, v in terms.items() if k.startswith("initial")),
                  "rollout_terms_mean": sum(v for k, v in terms.items() if k.startswith("rollout"))}
            (out / "cells" / f"{name}.json").write_text(json.dumps(_cell_summary(controller, pe, s)))

        write(f"naive_warm_start_{enc}", base, "naive_warm_start")
        for k in range(3):
            f = students / f"{enc}_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
            f.parent.mkdir(parents=True)
            f.write_bytes(b"")
            write(f"rl_warm_start_{enc}_seed{k}", {**base, "initial_term_z": base["initial_term_z"] + 10 * (k + 1),
                                                   "rollout_term_vx": base["rollout_term_vx"] + 5 * (k + 1)},
                  "rl_warm_start")
    monkeypatch.setattr(sys, "argv", ["cost_gap.py", "--seed-students", str(students), "--out", str(out),
                                      "--episodes", str(e), "--sampler-seeds", str(s)])
    cost_gap.main()
    gap = json.loads((out / "gap.json").read_text())["gap"]
    rows = {(r["p, F"], r["quantity"].strip()): r for r in gap}
    for p, F in cost_gap.ENCODINGS:
        z = rows[(f"{p}, {F}", "term z")]
        assert z["RL - naive (3 students)"] == "+20.00 [+10.00, +30.00]"
        assert z["median of the episodes' differences"] == "+20.00 [+10.00, +30.00]"  # equal on every episode
        assert [z[f"student {k} - naive"] for k in range(3)] == ["+10.00 [+10.00, +10.00]", "+20.00 [+20.00, +20.00]",
                                                                 "+30.00 [+30.00, +30.00]"]
        vx = rows[(f"{p}, {F}", "term vx")]["RL - naive (3 students)"]
        assert vx.replace("-", "+") == "+0.00 [+0.00, +0.00]"  # round-off may print -0.00
        assert rows[(f"{p}, {F}",
                     "initial cost (mean per episode)")]["RL - naive (3 students)"] == "+20.0 [+10.0, +30.0]"
        assert rows[(f"{p}, {F}", "rollout term vx")]["RL - naive (3 students)"] == "+10.0 [+5.0, +15.0]"
        assert rows[(f"{p}, {F}", "rollout term z")]["RL - naive (3 students)"].replace("-", "+") == "+0.0 [+0.0, +0.0]"
        key = "rollout cost, state (mean per episode, recorded solves)"
        assert rows[(f"{p}, {F}", key)]["RL - naive (3 students)"] == "+10.0 [+5.0, +15.0]"
    results = json.loads((out / "results.json").read_text())
    assert results["rl_warm_start_first-spline"]["training_seeds"] == 3
    assert (out / "cost_gap.png").stat().st_size > 0 and "3 students merged" in (out / "table.md").read_text()


def test_cost_gap_without_students_names_the_missing_file(tmp_path: Path) -> None:
    from dls_quadruped.cli import UserError
    from experiments import cost_gap

    with pytest.raises(UserError, match=r"no student .*first-spline_H10_dt0.02_seed0/exported/student.pt2 \(and 5 "
                                        r"more\)"):
        cost_gap.cells(tmp_path)


@pytest.mark.parametrize("argv, code, text", [(["--help"], 0, "--seed-students"),
                                              (["--scale", "huge"], 2, "invalid choice: 'huge'")])
def test_cost_gap_help_and_a_bad_scale(monkeypatch, capsys, argv, code, text):
    from experiments import cost_gap

    monkeypatch.setattr(sys, "argv", ["cost_gap.py", *argv])
    with pytest.raises(SystemExit) as err:
        cost_gap.main()
    out = capsys.readouterr()
    assert err.value.code == code and text in (out.out + out.err)


def test_table16_students_as_seeds_merge_each_rl_row(tmp_path: Path, monkeypatch) -> None:
    """table16_samples.py --seed-students on cached cells built by hand: each student's M = 4 000 cell costs
    exactly 1.1x its M = 10 000 cell on every episode, so the merged RL row's Δ initial is +10.0 % with a
    zero-width interval; a missing student of a selected cell is named before anything runs."""
    from dls_quadruped.cli import UserError
    from experiments import table16_samples as t16
    from experiments.warm_start_seeds import seed_student_cells

    rng = np.random.default_rng(1)
    e, s = 4, 2
    students, out = tmp_path / "students", tmp_path / "t16"
    (out / "cells").mkdir(parents=True)
    todo, rows = seed_student_cells(t16.cells(), students, only=["naive_warm_start_M4000"])  # no student needed
    assert rows["rl_warm_start_M4000"] == [f"rl_warm_start_M4000_seed{k}" for k in range(3)]
    assert "naive_warm_start_M4000" in {c.name for c in todo} and "rl_warm_start_M4000" not in {c.name for c in todo}
    with pytest.raises(UserError, match="first-spline_H10_dt0.02_seed0/exported/student.pt2"):
        seed_student_cells(t16.cells(), students, only=["rl_warm_start_M4000_seed0"])

    def write(name, controller, ic):
        pe = {"rl_reward": np.full((s, e), 2.2), "initial_cost": ic, "rollout_cost": 10 * ic,
              "survived": np.ones((s, e))}
        (out / "cells" / f"{name}.json").write_text(json.dumps(_cell_summary(controller, pe, s)))

    for k in range(3):
        f = students / f"first-spline_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
        f.parent.mkdir(parents=True)
        f.write_bytes(b"")
        ic = np.repeat(rng.uniform(40, 60, (1, e)), s, axis=0)  # equal across sampler seeds
        write(f"rl_warm_start_M10000_seed{k}", "rl_warm_start", ic)
        write(f"rl_warm_start_M4000_seed{k}", "rl_warm_start", 1.1 * ic)
    for m in (4000, 10000):
        write(f"naive_warm_start_M{m}", "naive_warm_start", rng.uniform(15, 25, (s, e)))
    only = [f"rl_warm_start_M{m}_seed{k}" for m in (4000, 10000) for k in range(3)]
    only += ["naive_warm_start_M4000", "naive_warm_start_M10000"]
    monkeypatch.setattr(sys, "argv", ["table16_samples.py", "--seed-students", str(students), "--out", str(out),
                                      "--episodes", str(e), "--sampler-seeds", str(s), "--only", *only])
    t16.main()
    results = json.loads((out / "results.json").read_text())
    assert results["rl_warm_start_M4000"]["training_seeds"] == 3
    assert np.asarray(results["rl_warm_start_M4000"]["per_episode"]["initial_cost"]).shape == (3, e)
    table = (out / "table.md").read_text()
    assert "3 students x the sampler seeds" in table and "+10.0 % [+10.0, +10.0]" in table


def test_table14_students_as_seeds_merge_each_rl_row(tmp_path: Path, monkeypatch) -> None:
    """table14_warm_start_encodings.py --seed-students on cached cells built by hand: every student's first-spline
    cell costs exactly 12 more than the naive warm start on every episode (the same on each sampler seed), so the
    merged RL row's Δ initial (paired) is +12.0 with a zero-width interval, and it merges the three students."""
    from experiments import table14_warm_start_encodings as t14

    rng = np.random.default_rng(2)
    e, s = 4, 2
    students, out = tmp_path / "students", tmp_path / "t14"
    (out / "cells").mkdir(parents=True)

    def write(name, controller, ic):
        pe = {"rl_reward": np.full((s, e), 2.2), "initial_cost": ic, "rollout_cost": 10 * ic,
              "vel_error": np.full((s, e), 0.1), "survived": np.ones((s, e))}
        (out / "cells" / f"{name}.json").write_text(json.dumps(_cell_summary(controller, pe, s)))

    naive = np.repeat(rng.uniform(15, 25, (1, e)), s, axis=0)  # equal across sampler seeds
    write("naive_warm_start_first-spline", "naive_warm_start", naive)
    write("rl_baseline", "rl_baseline", rng.uniform(60, 90, (s, e)))
    for k in range(3):
        f = students / f"first-spline_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
        f.parent.mkdir(parents=True)
        f.write_bytes(b"")
        write(f"rl_warm_start_first-spline_seed{k}", "rl_warm_start", naive + 12.0)
    only = [f"rl_warm_start_first-spline_seed{k}" for k in range(3)] + ["naive_warm_start_first-spline", "rl_baseline"]
    monkeypatch.setattr(sys, "argv", ["table14.py", "--seed-students", str(students), "--out", str(out),
                                      "--episodes", str(e), "--sampler-seeds", str(s), "--only", *only])
    t14.main()
    results = json.loads((out / "results.json").read_text())
    assert results["rl_warm_start_first-spline"]["training_seeds"] == 3
    table = (out / "table.md").read_text()
    assert "3 students x the sampler seeds" in table and "+12.0 [+12.0, +12.0]" in table


def test_fig32_students_as_seeds_merge_the_warm_start_row(tmp_path: Path, monkeypatch) -> None:
    """table18_multi_policy.py --seed-students on cached cells built by hand: base alone survives episodes 1 and 3
    of 4; every student survives those and episode 0 too, so each student's and the merged row's paired survival
    difference is +0.250 (1, 0, 0, 0 over the episodes); a resample without episode 0 has probability
    (3/4)^4 = 32 % > 2.5 %, so the interval's lower end is 0 by hand; the merged row holds the three students."""
    from experiments import table18_multi_policy as t18

    e = 4
    students, out = tmp_path / "students", tmp_path / "fig32"
    (out / "cells").mkdir(parents=True)

    def write(name, controller, survived):
        pe = {"rl_reward": np.full((1, e), 2.0), "rl_return": 10 * np.asarray([survived], dtype=float),
              "initial_cost": np.full((1, e), 50.0), "survived": np.asarray([survived], dtype=float)}
        (out / "cells" / f"{name}.json").write_text(json.dumps(_cell_summary(controller, pe, 1)))

    write("alone_base_survival", "rl_baseline", [0, 1, 0, 1])
    for k in range(3):
        f = students / f"first-spline_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
        f.parent.mkdir(parents=True)
        f.write_bytes(b"")
        write(f"ws_base_survival_seed{k}", "rl_warm_start", [1, 1, 0, 1])
    monkeypatch.setattr(sys, "argv", ["t18.py", "--seed-students", str(students), "--out", str(out),
                                      "--episodes", str(e), "--sampler-seeds", "1"])
    t18.main()
    results = json.loads((out / "results.json").read_text())
    assert results["ws_base_survival"]["training_seeds"] == 3
    table = (out / "fig32_seeds.md").read_text()
    assert "3 students" in table and table.count("+0.250 [+0.000, +0.") == 4  # merged + each student
    assert "| base alone | 50 % " in table
    from dls_quadruped.cli import run_cli

    monkeypatch.setattr(sys, "argv", ["t18.py", "--seed-students", str(students), "--stairs", "--out", str(out)])
    with pytest.raises(SystemExit) as err:
        run_cli(t18.main)
    assert err.value.code == 2


@pytest.mark.parametrize("script", ["table14_warm_start_encodings", "table16_samples", "table17_gait_optimisation",
                                    "table18_multi_policy"])
@pytest.mark.parametrize("argv, code, text", [(["--help"], 0, "--seed-students"),
                                              (["--seed-students"], 2, "expected one argument"),
                                              (["--seed-students", "nowhere"], 2,
                                               ("error: --seed-students nowhere: no student nowhere/"))])
def test_table16_and_17_help_a_bad_flag_and_a_missing_student(monkeypatch, capsys, tmp_path, script, argv, code, text):
    import importlib

    from dls_quadruped.cli import run_cli

    module = importlib.import_module(f"experiments.{script}")
    monkeypatch.setattr(sys, "argv", [f"{script}.py", "--out", str(tmp_path), *argv])
    with pytest.raises(SystemExit) as err:
        run_cli(module.main)
    out = capsys.readouterr()
    assert err.value.code == code and text in (out.out + out.err) and "Traceback" not in out.err
    if argv[-1] == "nowhere":  # the first missing student named in full (Table 14's list starts at discrete-discrete)
        first = "discrete-discrete" if script.startswith("table14") else "first-spline"
        assert f"nowhere/{first}_H10_dt0.02_seed0/exported/student.pt2" in out.err


def test_student_path_prefers_a_given_folders_first_spline_student(tmp_path: Path) -> None:
    """first-spline H = 10 dt = 0.02 s is the committed student unless ``--students`` was given and holds its own
    (the expert-seed runs pass each seed's student that way); other settings always come from the folder."""
    from experiments.warm_start_common import student_path

    committed = tmp_path / "committed.pt2"
    committed.write_bytes(b"")
    folder = tmp_path / "students"
    own = folder / "first-spline_H10_dt0.02" / "exported" / "student.pt2"
    other = folder / "spline-spline_H10_dt0.02" / "exported" / "student.pt2"
    for f in (own, other):
        f.parent.mkdir(parents=True)
        f.write_bytes(b"")
    assert student_path(folder, "first", "spline", 10, 0.02, committed) == committed
    assert student_path(folder, "first", "spline", 10, 0.02, committed, prefer_folder=True) == own
    assert student_path(tmp_path / "empty", "first", "spline", 10, 0.02, committed, prefer_folder=True) == committed
    assert student_path(folder, "spline", "spline", 10, 0.02, committed) == other
    assert student_path(folder, "discrete", "spline", 10, 0.02, committed, prefer_folder=True) is None
