"""bench/device_loop.py: the host path (``cpu`` backend, ``cpp`` kernel) and the device path (``warp-cpu``,
``warp`` kernel) of the closed loop on the same episodes, end to end at a small size (slow, needs the [gpu] extra).

The two paths share the episodes (the same commands row by row) and differ by simulator and noise stream, so their
per-episode values differ, but by no more than an episode's values differ between two sampler seeds on one path
plus a margin: a device path that broke the loop (a robot that falls, costs of another state) fails here."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dls_quadruped.bench import device_loop as D


@pytest.mark.slow
def test_both_paths_play_the_same_episodes_alike(tmp_path):
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    result = D.main(["--controllers", "naive_warm_start", "--episodes", "2", "--seconds", "1.0", "--samples", "128",
                     "--out", str(tmp_path)])
    assert json.loads((tmp_path / "device_loop.json").read_text())["settings"]["paths"]["warp_cpu"]["kernel"] == "warp"
    runs = result["controllers"]["naive_warm_start"]["runs"]
    assert set(runs) == set(D.PATHS)
    for run in runs.values():
        assert run["survival"] == 1.0 and run["mpc_fallbacks"] == 0
        assert all(np.isfinite(run["per_episode"][k]).all() and len(run["per_episode"][k]) == 2 for k in D.METRICS)
    reward = {run: np.array(r["per_episode"]["rl_reward"]) for run, r in runs.items()}
    seed_gap = np.abs(reward["cpu_next_seed"] - reward["cpu"]).max()
    assert np.abs(reward["warp_cpu"] - reward["cpu"]).max() <= seed_gap + 0.1  # reward per step ~2.2
    assert "| naive_warm_start | rl_reward |" in D.table(result)
