"""The gymnasium views of ``LocomotionEnv`` (``envs/gym_env.py``, ``envs/gym_spaces.py``).

Checks: every task registered and built by ``make_vec``; the action box worked out by hand and
cross-checked against the clip it describes; observations inside their space; the view steps
bit-identically to the native env; final observations, time-outs and episode statistics by hand and
against gymnasium's own ``RecordEpisodeStatistics`` on the numpy view; the one-robot view passes
``check_env``.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv

from dls_quadruped.control.latent_action import LatentActionConfig, clip, denormalise
from dls_quadruped.envs.config import available_tasks, load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.gym_env import (
    TASK_IDS,
    LocomotionGymEnv,
    LocomotionVectorEnv,
    task_id,
)
from dls_quadruped.envs.gym_spaces import FLOAT32_MARGIN, action_bounds

ROUGH_SMALL = {"scene": {"num_workers": 0}, "terrain": {"num_rows": 2}}  # noise on, every terrain type


def _actions(gen: torch.Generator, n: int, scale: float, no_tangential: bool = False) -> torch.Tensor:
    """(n, 28) actions uniform in scale x the action box (F_x, F_y zeroed if asked)."""
    low, high = (torch.as_tensor(b, dtype=torch.float32) for b in action_bounds(LatentActionConfig()))
    a = low + (high - low) * torch.rand(n, 28, generator=gen)
    mid = (low + high) / 2
    a = mid + scale * (a - mid)
    if no_tangential:
        a[:, [16 + 3 * leg + k for leg in range(4) for k in (0, 1)]] = 0.0
    return a


def test_every_task_is_registered_and_make_vec_builds_the_view():
    assert sorted(TASK_IDS) == sorted(task_id(t) for t in available_tasks())
    assert {"dls_quadruped/Base-v0", "dls_quadruped/Rough-v0", "dls_quadruped/Speed-v0",
            "dls_quadruped/Climb-v0"} <= set(gymnasium.registry)
    envs = gymnasium.make_vec("dls_quadruped/Base-v0", num_envs=3, num_workers=0, seed=0)
    try:
        assert isinstance(envs, VectorEnv) and isinstance(envs.unwrapped, LocomotionVectorEnv)
        assert envs.num_envs == 3 and envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        assert envs.single_observation_space["policy"].shape == (259,)  # Table 2 + command
        assert envs.observation_space["policy"].shape == (3, 259)
        assert envs.single_action_space.shape == (28,) and envs.action_space.shape == (3, 28)
        obs, info = envs.reset(seed=0)
        assert obs["policy"].shape == (3, 259) and obs["policy"].dtype == torch.float32 and info == {}
        obs, reward, terminated, truncated, info = envs.step(torch.zeros(3, 28))
        assert reward.shape == (3,) and terminated.dtype == truncated.dtype == torch.bool
        assert torch.equal(info["time_outs"], truncated)
    finally:
        envs.close()


def test_action_box_by_hand_and_against_the_clip():
    low, high = action_bounds(LatentActionConfig())
    # f: ([0, 3] Hz - 1.5) / 0.2; d: ([0, 1] - 0.6) / 0.03; p: [-0.10, 0.15] m, [-0.10, 0.10] m / (0.05 x 0.35 m)
    np.testing.assert_allclose(low[:4], -7.5), np.testing.assert_allclose(high[:4], 7.5)
    np.testing.assert_allclose(low[4:8], -20.0), np.testing.assert_allclose(high[4:8], 0.4 / 0.03)
    np.testing.assert_allclose(low[8:16:2], -0.10 / 0.0175), np.testing.assert_allclose(high[8:16:2], 0.15 / 0.0175)
    np.testing.assert_allclose(low[9:16:2], -0.10 / 0.0175), np.testing.assert_allclose(high[9:16:2], 0.10 / 0.0175)
    # F_x,y: mu m g / (0.025 m g) = 0.5 / 0.025; F_z: (0 - m g) / 0.1 m g with 1 leg, (m g - m g / 4) / 0.1 m g with 4
    fxy = [16 + 3 * leg + k for leg in range(4) for k in (0, 1)]
    fz = [16 + 3 * leg + 2 for leg in range(4)]
    np.testing.assert_allclose(low[fxy], -20.0), np.testing.assert_allclose(high[fxy], 20.0)
    np.testing.assert_allclose(low[fz], -10.0), np.testing.assert_allclose(high[fz], 7.5)
    # the box is where the clip does nothing: its corners are untouched, a step beyond each is clipped
    cfg = LatentActionConfig()
    for bound, stance in ((high, 4.0), (low, 1.0)):
        corner = torch.tensor(bound, dtype=torch.float64)
        corner[fxy] = 0.0  # the friction cone couples F_xy with F_z: checked alone below
        _, violation = clip(denormalise(corner, stance, cfg), cfg)
        assert violation.abs().max() < 1e-9
        beyond = corner + 1e-3 * torch.sign(corner)
        _, violation = clip(denormalise(beyond, stance, cfg), cfg)
        assert (violation[:16] != 0).all() and (violation[fz] != 0).all()
    tangential = torch.zeros(28, dtype=torch.float64)
    tangential[fz], tangential[16] = float(high[fz[0]]), 20.0  # F_z = m g (4 legs), F_x = mu m g: on the cone
    assert clip(denormalise(tangential, 4.0, cfg), cfg)[1].abs().max() < 1e-9
    tangential[16] = 20.01
    assert clip(denormalise(tangential, 4.0, cfg), cfg)[1][16] > 0


def test_observations_stay_in_their_space_with_noise_and_large_actions():
    envs = LocomotionVectorEnv(6, "rough", overrides=ROUGH_SMALL, seed=3, final_obs="all")
    try:
        box = envs.single_observation_space["policy"]
        names = [t.name for t in envs.env.observation_manager.groups["policy"]]
        dims = envs.env.observation_manager.dims["policy"]
        start = {n: sum(dims[m] for m in names[:i]) for i, n in enumerate(names)}
        # true bounds, widened by the noise (rough: noise_scale 1) and the float32 margin only
        scan = slice(start["height_scan"], start["height_scan"] + 187)
        np.testing.assert_allclose(box.high[scan], 1.0 + 0.1 + FLOAT32_MARGIN, rtol=1e-6)
        phase = slice(start["leg_phase"], start["leg_phase"] + 4)
        np.testing.assert_allclose(box.low[phase], -FLOAT32_MARGIN, atol=1e-9)
        assert np.isinf(box.high[start["base_lin_vel"]])
        gen = torch.Generator().manual_seed(0)
        obs, _ = envs.reset(seed=3)
        for k in range(60):
            assert box.contains(obs["policy"].numpy()[k % 6]) and all(
                envs.single_observation_space.contains({"policy": row}) for row in obs["policy"].numpy())
            obs, _, _, _, info = envs.step(_actions(gen, 6, scale=3.0))  # far outside the box: clipped
            if "final_obs" in info:
                assert all(box.contains(row) for row in info["final_obs"]["policy"].numpy())
    finally:
        envs.close()


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_the_view_steps_exactly_as_the_native_env():
    native = LocomotionEnv(load_task("rough", overrides=ROUGH_SMALL), num_envs=4, seed=5, verbose=False)
    view = LocomotionVectorEnv(4, "rough", overrides=ROUGH_SMALL, seed=5, final_obs="all")
    try:
        gen = torch.Generator().manual_seed(1)
        obs_n, _ = native.reset(seed=5)
        obs_v, _ = view.reset(seed=5)
        ended = 0
        for _ in range(80):
            actions = _actions(gen, 4, scale=1.5)
            obs_n, rew_n, dones_n, extras_n = native.step(actions)
            obs_v, rew_v, term_v, trunc_v, _ = view.step(actions)
            assert torch.equal(obs_n["policy"], obs_v["policy"]) and torch.equal(rew_n, rew_v)
            assert torch.equal(dones_n.bool(), term_v | trunc_v)
            assert torch.equal(extras_n["time_outs"].bool(), trunc_v)
            ended += int(dones_n.sum())
        assert ended > 0  # final observations of every fall were computed on the way, and changed nothing
    finally:
        native.close()
        view.close()


def test_final_observation_time_out_and_episode_statistics_by_hand():
    overrides = {"scene": {"num_workers": 0}, "env": {"episode_length_s": 0.2}}  # 10 policy steps
    envs = LocomotionVectorEnv(2, "base", overrides=overrides, seed=0)
    try:
        gen = torch.Generator().manual_seed(2)
        envs.reset(seed=0)
        last = envs.env.observation_manager.dims["policy"]
        names = [t.name for t in envs.env.observation_manager.groups["policy"]]
        a0 = sum(last[n] for n in names[:names.index("last_action")])
        rewards = []
        for k in range(10):
            actions = _actions(gen, 2, scale=0.1, no_tangential=True)  # small, inside the box: applied as sent
            obs, reward, terminated, truncated, info = envs.step(actions)
            rewards.append(reward.double())
        assert k == 9 and truncated.all() and not terminated.any()
        assert info["_episode"].all() and info["_final_obs"].all()
        assert torch.equal(info["episode"]["l"], torch.tensor([10, 10]))
        torch.testing.assert_close(info["episode"]["r"], torch.stack(rewards).sum(0), rtol=0, atol=1e-12)
        # the last observation holds the episode's last applied action; the new episode starts from zero
        torch.testing.assert_close(info["final_obs"]["policy"][:, a0:a0 + 28], actions, rtol=0, atol=1e-5)
        assert (obs["policy"][:, a0:a0 + 28] == 0).all()
        _, _, _, _, info = envs.step(torch.zeros(2, 28))
        assert "episode" not in info and "final_obs" not in info
    finally:
        envs.close()


def test_record_episode_statistics_on_the_numpy_view_agrees():
    pytest.importorskip("array_api_compat")
    from gymnasium.wrappers.vector import ArrayConversion, RecordEpisodeStatistics

    kwargs = {"overrides": {"scene": {"num_workers": 0}, "env": {"episode_length_s": 0.3}}, "seed": 4}
    ours = LocomotionVectorEnv(3, "base", **kwargs)
    theirs = RecordEpisodeStatistics(ArrayConversion(LocomotionVectorEnv(3, "base", episode_statistics=False,
                                                                         **kwargs), env_xp=torch, target_xp=np))
    try:
        gen = torch.Generator().manual_seed(3)
        ours.reset(seed=4)
        obs_np, _ = theirs.reset(seed=4)
        assert isinstance(obs_np["policy"], np.ndarray)
        finished = 0
        for _ in range(40):
            actions = _actions(gen, 3, scale=1.0)
            _, _, _, _, info = ours.step(actions)
            _, _, _, _, info_np = theirs.step(actions.numpy())
            assert ("episode" in info) == ("episode" in info_np)
            if "episode" in info:
                np.testing.assert_array_equal(info["_episode"].numpy(), info_np["_episode"])
                np.testing.assert_array_equal(info["episode"]["l"].numpy(), info_np["episode"]["l"])
                np.testing.assert_array_equal(info["episode"]["r"].numpy(), info_np["episode"]["r"])
                finished += int(info_np["_episode"].sum())
        assert finished >= 3 * 2  # time-outs every 15 steps, and falls
    finally:
        ours.close()
        theirs.close()


def test_one_robot_view_passes_check_env_and_hands_out_the_next_episode():
    env = gymnasium.make("dls_quadruped/Base-v0", num_workers=0, seed=0).unwrapped
    try:
        assert isinstance(env, LocomotionGymEnv)
        check_env(env, skip_render_check=True)
        env.reset(seed=7)
        for _ in range(200):
            obs, _, terminated, truncated, info = env.step(env.action_space.high * 3.0)  # falls
            if terminated or truncated:
                break
        assert terminated and "episode" in info and isinstance(obs["policy"], np.ndarray)
        started = env.vec.env.obs_buf["policy"][0].numpy()
        first, _ = env.reset()  # the episode the env began when the last one ended, not another
        np.testing.assert_array_equal(first["policy"], started)
    finally:
        env.close()


def test_reset_seed_replays_and_bad_options_are_named():
    envs = LocomotionVectorEnv(2, "rough", overrides=ROUGH_SMALL, seed=0)
    try:
        a, _ = envs.reset(seed=11)
        envs.step(torch.zeros(2, 28))
        b, _ = envs.reset(seed=11)
        assert torch.equal(a["policy"], b["policy"])
        keys, _ = envs.reset(seed=11, options={"episode_keys": [1, 1]})
        assert torch.equal(keys["policy"][0], keys["policy"][1])  # one episode key: the same noise and command
        with pytest.raises(ValueError, match=r"unknown reset options \['reset_mask'\]; allowed: \['episode_keys'\]"):
            envs.reset(options={"reset_mask": np.ones(2, bool)})
        gen = torch.Generator().manual_seed(5)
        for _ in range(100):  # falls, no time-out: by default no final observation (nothing to bootstrap)
            _, _, terminated, truncated, info = envs.step(_actions(gen, 2, scale=3.0))
            assert not truncated.any()
            if terminated.any():
                assert "final_obs" not in info and info["_episode"].any()
                break
        assert terminated.any()
    finally:
        envs.close()
    with pytest.raises(ValueError, match=r"final_obs must be one of \['truncated', 'all', 'none'\], got 'yes'"):
        LocomotionVectorEnv(1, "base", final_obs="yes")
