"""The gait/warm-start control's decomposition (experiments/gait_control.py): on arms built additively by hand the
Shapley parts recover the parts, they add up to the total, the interaction is what does not add, and the labels
follow the plan's margins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from experiments import gait_control as G

REPO = Path(__file__).resolve().parents[2]


def _results(gait: np.ndarray, forces: np.ndarray, inter: float = 0.0, noise: float = 0.0) -> dict:
    """Arms over 3 students x 40 episodes: N an episode baseline, G = N + gait, F = N + forces, RL = N + gait +
    forces + inter; ``gait`` and ``forces`` per student (3,)."""
    rng = np.random.default_rng(0)
    n = rng.normal(30.0, 4.0, size=40)
    eps = lambda: noise * rng.normal(size=(3, 40))
    arms = {"N": n[None], "G": n + gait[:, None] + eps(), "F": n + forces[:, None] + eps(),
            "RL": n + gait[:, None] + forces[:, None] + inter + eps()}
    return {f"{G.ARMS[a]}_first-spline": {"per_episode": {"initial_cost": v.tolist()}} for a, v in arms.items()}


def _by_name(rows: list[dict]) -> dict[str, dict]:
    return {r["contrast"]: r for r in rows if r["key"] == "initial_cost"}


def test_shapley_parts_recover_additive_parts_and_add_up_to_the_total() -> None:
    rows = _by_name(G.contrast_rows(_results(np.array([6.0, 8.0, 10.0]), np.array([1.0, 2.0, 3.0]))))
    assert rows["total RL - N"]["mean"] == pytest.approx(10.0)  # (8 + 2) on average over the students
    assert rows["gait (Shapley): (G - N + RL - F) / 2"]["mean"] == pytest.approx(8.0)
    assert rows["forces (Shapley): (F - N + RL - G) / 2"]["mean"] == pytest.approx(2.0)
    assert rows["interaction: RL - G - F + N"]["mean"] == pytest.approx(0.0, abs=1e-12)
    for name in ("gait, naive forces: G - N", "gait, student forces: RL - F"):  # no interaction: both conditionals
        assert rows[name]["mean"] == pytest.approx(8.0)
    assert rows["gait (Shapley): (G - N + RL - F) / 2"]["student 2"] == "+10.0"
    assert rows["gait (Shapley): (G - N + RL - F) / 2"]["share of total"] == "80 %"
    # students resampled: the gait's interval spans the students' spread (6 .. 10), the episodes add nothing
    lo, hi = rows["gait (Shapley): (G - N + RL - F) / 2"]["ci95"]
    assert 6.0 - 1e-9 <= lo < 8.0 < hi <= 10.0 + 1e-9


def test_an_interaction_splits_evenly_between_the_shapley_parts() -> None:
    rows = _by_name(G.contrast_rows(_results(np.full(3, 4.0), np.full(3, 1.0), inter=2.0)))
    assert rows["interaction: RL - G - F + N"]["mean"] == pytest.approx(2.0)
    assert rows["gait, naive forces: G - N"]["mean"] == pytest.approx(4.0)
    assert rows["gait, student forces: RL - F"]["mean"] == pytest.approx(6.0)
    assert rows["gait (Shapley): (G - N + RL - F) / 2"]["mean"] == pytest.approx(5.0)
    assert rows["forces (Shapley): (F - N + RL - G) / 2"]["mean"] == pytest.approx(2.0)
    assert rows["total RL - N"]["mean"] == pytest.approx(7.0)


def test_labels_follow_the_plans_margins() -> None:
    rows = _by_name(G.contrast_rows(_results(np.full(3, 8.0), np.zeros(3), noise=0.5)))
    assert rows["gait (Shapley): (G - N + RL - F) / 2"]["label"] == "> 0"
    assert rows["forces (Shapley): (F - N + RL - G) / 2"]["label"] == "within +-5"  # ~0 +- 0.2, margin 5
    assert G.label([-1.0, 6.0], 5.0) == "inconclusive" and G.label([-3.0, -0.1], 5.0) == "< 0"
    assert G.label([-0.01, 0.01], None) == "inconclusive"  # the return has no margin: never "within"


def test_the_student_arms_run_once_per_student_and_the_naive_arm_once(tmp_path) -> None:
    for k in range(3):
        path = tmp_path / f"first-spline_H10_dt0.02_seed{k}" / "exported" / "student.pt2"
        path.parent.mkdir(parents=True)
        path.write_bytes(b"")
    todo, rows = G.cells(tmp_path)
    names = [c.name for c in todo]
    assert names.count("naive_warm_start_first-spline") == 1
    for ctrl in ("rl_warm_start", "rl_gait_naive_forces", "naive_gait_rl_forces"):
        assert rows[f"{ctrl}_first-spline"] == [f"{ctrl}_first-spline_seed{k}" for k in range(3)]
    assert len(todo) == 10


def test_a_missing_arm_gives_no_row() -> None:
    res = _results(np.full(3, 1.0), np.full(3, 1.0))
    del res["naive_gait_rl_forces_first-spline"]
    assert G.contrast_rows(res) == []


def test_missing_students_are_refused_in_one_line_before_any_cell(tmp_path) -> None:
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "experiments.gait_control", "--seed-students", str(tmp_path / "none"),
                          "--out", str(tmp_path / "out")], check=False, cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode != 0
    assert "no student" in res.stderr and "first-spline_H10_dt0.02_seed0" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out" / "cells").exists() or not any((tmp_path / "out" / "cells").iterdir())
    bad = subprocess.run([sys.executable, "-m", "experiments.gait_control", "--scale", "huge"], check=False, cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--scale" in bad.stderr
