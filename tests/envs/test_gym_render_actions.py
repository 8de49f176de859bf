"""The one-robot gymnasium view's options for other RL libraries: a [-1, 1]-normalised action space (mapped
linearly onto the raw box, checked by hand and against the raw view stepping the same episode) and
``render_mode="rgb_array"`` (gymnasium's own ``check_env`` with its render check, in a process that chooses EGL
before MuJoCo loads, as ``make play`` does)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from dls_quadruped.envs.gym_env import LocomotionGymEnv

REPO = Path(__file__).resolve().parents[2]


def test_normalised_actions_map_onto_the_raw_box_and_step_as_the_raw_view():
    raw = LocomotionGymEnv("base", num_workers=0, seed=3)
    unit = LocomotionGymEnv("base", num_workers=0, seed=3, normalize_actions=True)
    try:
        low, high = raw.action_space.low, raw.action_space.high
        assert unit.action_space == gymnasium.spaces.Box(-1.0, 1.0, (28,), np.float32)
        np.testing.assert_allclose(unit.raw_action(-np.ones(28)), low, rtol=0, atol=1e-6)
        np.testing.assert_allclose(unit.raw_action(np.ones(28)), high, rtol=0, atol=1e-5)
        np.testing.assert_allclose(unit.raw_action(np.zeros(28)), (low + high) / 2, rtol=0, atol=1e-5)
        assert np.array_equal(raw.raw_action(np.full(28, 0.5)), np.full(28, 0.5, np.float32))  # raw: unchanged
        raw.reset(seed=3)
        unit.reset(seed=3)
        u = np.random.default_rng(0).uniform(-1, 1, (5, 28)).astype(np.float32)
        for k in range(5):
            a, _, _, _, _ = raw.step(unit.raw_action(u[k]))
            b, _, _, _, _ = unit.step(u[k])
            np.testing.assert_array_equal(a["policy"], b["policy"])
        with pytest.raises(ValueError, match=r"action must have shape \(28,\)"):
            unit.step(np.zeros(27))
        check_env(unit, skip_render_check=True)
    finally:
        raw.close()
        unit.close()


def test_a_bad_render_mode_is_named():
    with pytest.raises(ValueError, match=r"render_mode must be None or one of \['rgb_array'\], got 'human'"):
        LocomotionGymEnv("base", num_workers=0, render_mode="human")


RENDER = r"""
import json, sys
import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env
import dls_quadruped.envs.gym_env  # registers the ids
env = gymnasium.make("dls_quadruped/Base-v0", num_workers=0, seed=0, render_mode="rgb_array",
                     normalize_actions=True).unwrapped
try:
    try:
        env.reset(seed=0)
        frame = env.render()
    except Exception as err:  # no OpenGL platform: reported, not failed
        print(json.dumps({"no_gl": repr(err)}))
        sys.exit(0)
    check_env(env)  # with its render check
    env.step(np.zeros(28, np.float32))
    later = env.render()
    print(json.dumps({"shape": list(frame.shape), "dtype": str(frame.dtype), "changed": bool((later != frame).any()),
                      "fps": env.metadata["render_fps"]}))
finally:
    env.close()
"""


def test_rgb_array_frames_pass_check_env():
    run = subprocess.run([sys.executable, "-c", RENDER], cwd=REPO, capture_output=True, text=True, timeout=300,
                         check=False,
                         env={**os.environ, "PYTHONPATH": str(REPO), "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    if "no_gl" in out:
        pytest.skip(f"no offscreen OpenGL (EGL) on this machine: {out['no_gl']}")
    assert out["shape"] == [360, 480, 3] and out["dtype"] == "uint8" and out["fps"] == 50
    assert out["changed"]  # the robot moved: the frame follows the env's state
