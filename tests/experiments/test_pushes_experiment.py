"""The preregistered calibration rule and verdict of ``experiments/pushes.py``, on hand-made rates."""

from __future__ import annotations

import pytest

from experiments.pushes import choose, refinement, verdict


def test_choose_picks_the_rate_closest_to_half_inside_the_band():
    assert choose({0.5: 1.0, 1.0: 0.72, 1.5: 0.62, 2.0: 0.41, 3.0: 0.1}) == 2.0  # |0.41-0.5| < |0.62-0.5|
    assert choose({1.0: 0.625, 1.5: 0.375}) == 1.0  # an exact tie: the smaller speed
    assert choose({1.0: 0.9, 2.0: 0.2}) is None  # nothing in [0.3, 0.7]
    assert choose({1.0: 0.3, 2.0: 0.71}) == 1.0  # the band's edges are inside


def test_refinement_steps_between_the_speeds_that_bracket_half():
    assert refinement({1.0: 0.9, 1.5: 0.8, 2.0: 0.2, 3.0: 0.0}) == [1.625, 1.75, 1.875]
    assert refinement({1.0: 1.0, 2.0: 0.9}) == []  # never below half: nothing brackets it


@pytest.mark.parametrize(("ci", "expected"), [([0.01, 0.2], "reproduced"), ([-0.2, -0.01], "contradicted"),
                                              ([-0.05, 0.1], "inconclusive"), ([0.0, 0.1], "inconclusive")])
def test_verdict_follows_the_rules(ci, expected):
    assert verdict(ci) == expected


def test_pushes_script_help_and_a_bad_stage():
    import subprocess
    import sys
    from pathlib import Path

    repo, cmd = Path(__file__).resolve().parents[2], [sys.executable, "-m", "experiments.pushes"]
    ok = subprocess.run([*cmd, "--help"], cwd=repo, capture_output=True, text=True, timeout=120, check=False)
    assert ok.returncode == 0 and "--push-speed" in ok.stdout and "calibrate" in ok.stdout
    bad = subprocess.run([*cmd, "sweep"], cwd=repo, capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "invalid choice: 'sweep'" in bad.stderr and "Traceback" not in bad.stderr


def test_pushes_with_three_students_merges_them_in_the_primary_contrast(tmp_path, monkeypatch):
    """``report --seed-students`` on cached cells built by hand: base alone survives episodes 0 and 2 of 4, students
    0 and 1 survive every episode, student 2 exactly base alone's; so base warm − base alone is 2/3 on episodes 1
    and 3 and 0 on the others: +1/3 on average, merged over 3 students; only the two primary arms are reported."""
    import json
    import sys

    import numpy as np

    from dls_quadruped.eval.metrics import episode_summary
    from experiments import pushes

    e = 4
    students, out = tmp_path / "students", tmp_path / "pushes"
    (out / "cells").mkdir(parents=True)

    def write(name, controller, survived):
        pe = {"survived": np.atleast_2d(survived).astype(float), "rl_return": 100.0 * np.atleast_2d(survived)}
        rate = float(np.mean(survived))
        cell = {"controller": controller, "episodes": e, "replicas": 1,
                "survival": {"rate": rate, "ci95": [rate, rate], "n": e},
                "per_episode": {k: v.tolist() for k, v in pe.items()},
                "rl_return": episode_summary(pe["rl_return"])}
        (out / "cells" / f"{name}.json").write_text(json.dumps(cell))

    alone = np.array([1, 0, 1, 0])
    write("base_alone", "rl_baseline", alone)
    for k, survived in enumerate([np.ones(e), np.ones(e), alone]):
        f = students / f"first-spline_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
        f.parent.mkdir(parents=True)
        f.write_bytes(b"")
        write(f"base_warm_seed{k}", "rl_warm_start", survived)
    monkeypatch.setattr(sys, "argv", ["pushes.py", "report", "--seed-students", str(students), "--out", str(out),
                                      "--episodes", str(e), "--sampler-seeds", "1", "--push-speed", "1.5"])
    pushes.main()
    report = json.loads((out / "report.json").read_text())
    assert report["students"] == 3 and set(report["arms"]) == {"base_alone", "base_warm"}
    assert report["primary"]["mean"] == pytest.approx(1 / 3)
    assert report["arms"]["base_warm"]["rate"] == pytest.approx(2 / 3 * 1 + 1 / 3 * 0.5)
    assert "x 3 students" in (out / "report.md").read_text()
