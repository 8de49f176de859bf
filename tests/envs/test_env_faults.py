"""Env faults: bad action batches are refused before any buffer changes; a NaN robot is reset alone;
the env state a checkpoint carries round-trips into a fresh env."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv

SMALL = {"scene": {"num_workers": 0}, "terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}


@pytest.fixture(scope="module")
def env(small_base_env):
    return small_base_env  # tests/conftest.py


def _snapshot(env) -> list[torch.Tensor]:
    am = env.action_manager
    return [b.clone() for b in (am.raw_action, am.prev_raw_action, am.applied_action, env.state.base_pos_w,
                                env.episode_length_buf)]


@pytest.mark.parametrize("bad, error, match", [
    (torch.zeros(28), ValueError, r"shape \(3, 28\).*got \(28,\)"),
    (torch.zeros(1, 28), ValueError, r"got \(1, 28\)"),
    (torch.zeros(3, 27), ValueError, r"got \(3, 27\)"),
    (torch.zeros(3, 28, dtype=torch.bool), TypeError, "real numbers"),
    ([[0.0] * 28] * 3, TypeError, "got list"),
    (np.array([["a"] * 28] * 3), TypeError, "real numbers"),
])
def test_bad_action_batches_raise_before_touching_buffers(env, bad, error, match):
    env.step(torch.randn(3, 28))
    before = _snapshot(env)
    with pytest.raises(error, match=match):
        env.step(bad)
    for a, b in zip(before, _snapshot(env)):
        assert torch.equal(a, b)


def test_numpy_and_autograd_actions_are_accepted(env):
    obs, *_ = env.step(np.random.default_rng(0).standard_normal((3, 28)))  # float64 numpy
    assert env.action_manager.raw_action.dtype == torch.float32
    policy = torch.nn.Linear(obs["policy"].shape[1], 28)
    action = policy(obs["policy"])  # outside torch.no_grad: carries autograd history
    assert action.requires_grad
    for _ in range(3):
        env.step(action)
    assert not env.action_manager.raw_action.requires_grad
    env.reset()  # issue 9: reset failed for every later call after one such action
    env.step(torch.zeros(3, 28))


def test_nan_robot_is_reset_and_counted_others_go_on(env):
    env.reset()
    for _ in range(5):
        env.step(torch.zeros(3, 28))
    length_before = env.episode_length_buf.clone()
    action = torch.zeros(3, 28)
    action[1, 4] = float("nan")
    action[2, 0] = float("inf")
    env.episode_log.read()  # what earlier steps logged
    obs, reward, dones, extras = env.step(action)
    assert dones.tolist() == [0, 1, 1]
    assert env.episode_log.read()["Episode_Termination/nonfinite_action"] == 2.0
    assert not extras["time_outs"][1:].any()  # a failure, not a time limit: PPO must not bootstrap it
    assert env.episode_length_buf.tolist() == [int(length_before[0]) + 1, 0, 0]
    assert torch.isfinite(obs["policy"]).all() and torch.isfinite(reward).all()
    assert torch.isfinite(env.action_manager.raw_action).all()
    _, _, dones, extras = env.step(torch.zeros(3, 28))
    assert not dones.any() and env.episode_log.read() == {}  # no reset, nothing logged


def test_env_state_round_trips_into_a_fresh_env():
    task = load_task("climb", overrides=SMALL)
    a = LocomotionEnv(task, num_envs=4, seed=1, verbose=False)
    b = LocomotionEnv(task, num_envs=4, seed=2, verbose=False)
    try:
        a.scene.update_levels(torch.arange(4), torch.tensor([2, 1, 0, 2]) - a.scene.terrain_levels)
        a.command_manager.params["lin_vel_x"] = [0.3, 0.9]
        pen = a.curriculum_manager.state["penalties_when_walking"]
        pen["enabled"] = True
        a.reward_manager.weights.update(pen["targets"])
        a.curriculum_manager.values["penalties"] = 1.0
        a.common_step_counter = 1234
        state = a.state_dict()
        b.load_state_dict(state)
        assert b.scene.terrain_levels.tolist() == [2, 1, 0, 2]
        torch.testing.assert_close(b.scene.env_origins, a.scene.env_origins)
        assert b.command_manager.term.params["lin_vel_x"] == [0.3, 0.9]  # the term reads this dict
        assert b.reward_manager.weights == a.reward_manager.weights and b.reward_manager.weights["action_rate"] != 0
        assert b.curriculum_manager.state["penalties_when_walking"]["enabled"]
        assert b.curriculum_manager.values["penalties"] == 1.0 and b.common_step_counter == 1234
        # the episodes in progress go on (a's robots stay where they were, on their old tiles: a moved
        # its levels without resetting them), and the RNG continues where a's stopped
        assert torch.equal(b.state.base_pos_w, a.state.base_pos_w)
        assert torch.equal(torch.rand(5), (torch.set_rng_state(state["rng_cpu"]), torch.rand(5))[1])
        # without the episodes (an older checkpoint, another num_envs) robots restart on their restored tiles
        del state["episodes"]
        b.load_state_dict(state)
        torch.testing.assert_close(b.state.base_pos_w[:, :2], b.scene.env_origins[:, :2], atol=0.6, rtol=0)
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("num_envs", [0, -3, 2.5])
def test_num_envs_zero_is_an_error_not_the_default(num_envs):
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
        LocomotionEnv(load_task("base", overrides=SMALL), num_envs=num_envs, verbose=False)
