"""bench/reference_runs.py: the committed references and the deviation report the GPU check prints."""

from __future__ import annotations

import numpy as np
import pytest

from dls_quadruped.bench import reference_runs as R


def test_committed_references_hold_every_scenario_on_both_backends():
    refs = np.load(R.REFERENCE_PATH)
    for backend in ("cpu", "warp-cpu"):
        for name in R.SCENARIOS:
            a = refs[f"{backend}/{name}"]
            assert a.ndim == 3 and a.shape[2] == 19 and np.isfinite(a).all(), (backend, name)
    # the trot walked forward (x of every robot after 1 s) and the standing robots stayed at standing height
    assert (refs["cpu/trot"][-1, :, 0] > 0.1).all()
    assert (refs["cpu/standing"][-1, :, 2] > 0.3).all()


def test_compare_reports_the_largest_deviation_per_part_by_hand():
    ref = np.zeros((2, 3, 19), dtype=np.float32)
    traj = ref.copy()
    traj[1, 2, 0] = 5e-5  # base x of robot 2 at the last step
    traj[0, 1, 4] = -2e-4  # quaternion x of robot 1
    traj[1, 0, 10] = 3e-3  # a joint of robot 0
    out = R.compare("standing", traj, ref)
    assert out["base_pos_m"] == pytest.approx(5e-5) and out["final_base_pos_m"] == pytest.approx(5e-5)
    assert out["quat"] == pytest.approx(2e-4) and out["joints_rad"] == pytest.approx(3e-3)
    assert out["per_robot_base_pos_m"] == pytest.approx([0.0, 0.0, 5e-5])
    assert out["ok"] is False  # quaternion 2e-4 > 1e-4 and joint 3e-3 > 1e-3 (TOLERANCES["standing"])
    traj[0, 1, 4], traj[1, 0, 10] = 0.0, 0.0
    assert R.compare("standing", traj, ref)["ok"] is True


def test_compare_refuses_another_shape_and_flags_nan():
    ref = np.zeros((2, 3, 19))
    assert R.compare("trot", np.zeros((3, 3, 19)), ref)["ok"] is False
    bad = ref.copy()
    bad[0, 0, 0] = np.nan
    out = R.compare("trot", bad, ref)
    assert out["base_pos_m"] == float("inf") and out["ok"] is False
