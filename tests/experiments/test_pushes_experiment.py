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
