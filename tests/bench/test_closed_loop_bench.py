"""bench.closed_loop on a tiny setting: the profile's parts are fractions of the wall time that add up."""

from __future__ import annotations

import json
from pathlib import Path

from dls_quadruped.bench.closed_loop import main


def test_closed_loop_bench_profile_adds_up(tmp_path: Path) -> None:
    res = main(["--robots", "2", "--seconds", "0.1", "--samples", "200", "--out", str(tmp_path)])
    assert json.loads((tmp_path / "closed_loop.json").read_text())["rows"] == json.loads(json.dumps(res["rows"]))
    assert len(res["rows"]) == 2
    for row in res["rows"]:
        share = row["share"]
        assert all(0.0 <= v <= 1.0 for v in share.values())
        assert abs(sum(share.values()) - 1.0) < 1e-6  # kernel + rest of solve + policy + probe + env/sim = wall
        assert row["robot_seconds_per_second"] > 0 and row["kernel_alone_ms_B1"] > 0


def test_closed_loop_bench_one_and_two_student_groups(tmp_path: Path) -> None:
    res = main(["--robots", "2", "--seconds", "0.1", "--samples", "200", "--controllers", "rl_warm_start",
                "naive_warm_start", "--students", "1", "2", "--out", str(tmp_path)])
    groups = [(r["controller"], r["students"]) for r in res["rows"]]
    assert groups == [("rl_warm_start", 1), ("rl_warm_start", 2), ("naive_warm_start", 1)]  # no 2-group naive row
