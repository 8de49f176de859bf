"""bench.closed_loop on a tiny setting: the profile's parts are the loop's own timers over its wall time."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from dls_quadruped.bench import closed_loop as closed_loop_bench
from dls_quadruped.bench.closed_loop import main


def test_closed_loop_bench_profile_adds_up(tmp_path: Path, monkeypatch) -> None:
    """Each row's shares are the closed loop's own timers (read from its traces, beside the bench) over its wall
    time, the simulator's share what the timed parts leave; the loop's wall time lies within the call's."""
    runs = []  # (timing of the loop, seconds the call took), in call order: a warm-up, then the measured run

    def timed(*args, **kwargs):
        tic = time.perf_counter()
        traces = original(*args, **kwargs)
        runs.append((dict(traces.timing), time.perf_counter() - tic))
        return traces

    original = closed_loop_bench.run_closed_loop
    monkeypatch.setattr(closed_loop_bench, "run_closed_loop", timed)
    res = main(["--robots", "2", "--seconds", "0.1", "--samples", "200", "--out", str(tmp_path)])
    assert json.loads((tmp_path / "closed_loop.json").read_text())["rows"] == json.loads(json.dumps(res["rows"]))
    assert len(res["rows"]) == 2 and len(runs) == 4
    for row, (t, call_s) in zip(res["rows"], runs[1::2], strict=True):
        wall = t["wall"]
        assert row["wall_s"] == wall and 0.0 < wall <= call_s
        # the timers cover disjoint stretches of the loop: the kernel within the solves, and solves, policy
        # queries and probe within the wall time
        assert 0.0 < t["kernel"] <= t["solve"] and t["solve"] + t["policy"] + t["probe"] < wall
        expected = {"kernel": t["kernel"] / wall, "solve_without_kernel": (t["solve"] - t["kernel"]) / wall,
                    "policy": t["policy"] / wall, "probe": t["probe"] / wall,
                    "env_and_sim": (wall - t["solve"] - t["policy"] - t["probe"]) / wall}
        assert row["share"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert row["robot_seconds_per_second"] == pytest.approx(2 * 0.1 / wall, rel=1e-6)
        assert row["kernel_alone_ms_B1"] > 0


def test_closed_loop_bench_one_and_two_student_groups(tmp_path: Path) -> None:
    res = main(["--robots", "2", "--seconds", "0.1", "--samples", "200", "--controllers", "rl_warm_start",
                "naive_warm_start", "--students", "1", "2", "--out", str(tmp_path)])
    groups = [(r["controller"], r["students"]) for r in res["rows"]]
    assert groups == [("rl_warm_start", 1), ("rl_warm_start", 2), ("naive_warm_start", 1)]  # no 2-group naive row
