"""Students as seeds in the chapter-7.3 experiment scripts (``--seed-students``): each student-warm-started cell run
once per training seed's student and merged into one row, checked on cached cells built by hand (cost_gap, Tables
14 and 16, Fig. 32), and the scripts' one-line errors for a missing student or a bad flag."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


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
