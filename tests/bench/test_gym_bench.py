"""bench.gym_env measures the native env and the gymnasium view over the same env."""

from __future__ import annotations

import math

from dls_quadruped.bench.gym_env import measure


def test_gym_bench_measures_both_on_one_env():
    res = measure("base", num_envs=2, rounds=2, steps=2, num_workers=0, final_obs="all")
    assert len(res["rates"]["native"]) == len(res["rates"]["gymnasium"]) == 2
    assert res["native_steps_per_s"] > 0 and res["gymnasium_steps_per_s"] > 0
    assert math.isclose(res["overhead"], 1.0 - res["gymnasium_steps_per_s"] / res["native_steps_per_s"])
    assert res["workers"] == 0 and res["final_obs"] == "all" and 0.0 <= res["view_steps_with_a_reset"] <= 1.0
