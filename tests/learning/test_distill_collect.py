"""Sliding-window collection (thesis Algorithms 3-4): windows vs hand-built trajectories, dt spacing,
resets, beta mixing and schedules."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.learning.collect import SlidingWindows, beta, collect
from dls_quadruped.learning.distill_config import EncodingSection, SelectorSection
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import encode


def expected_windows(lengths: list[int], steps: int, horizon: int, stride: int) -> set[tuple]:
    """Looped reference: every (env, episode, start step) whose H actions at start, start+k, ...,
    start+(H-1)k all lie in one episode and were recorded within ``steps`` pushes."""
    out = set()
    for e, length in enumerate(lengths):
        for t_end in range(steps):  # global step of the window's last action
            episode, t_ep = divmod(t_end, length)
            start = t_ep - (horizon - 1) * stride
            if start >= 0:
                out.add((e, episode, start))
    return out


@pytest.mark.parametrize("horizon,stride", [(5, 1), (5, 2), (1, 1), (3, 3)])
def test_windows_match_hand_built_trajectories(horizon, stride, scripted_env, tag_expert):
    lengths = [7, 12, 30, 9]  # different episode lengths: resets at different steps
    env = scripted_env(lengths)
    windows = SlidingWindows(env.num_envs, 3, 28, horizon, stride)
    obs = env.get_observations()["policy"]
    seen = set()
    steps = 40
    for _ in range(steps):
        act = tag_expert(obs)
        ids, start_obs, acts = windows.push(obs, act)
        for i in range(len(ids)):
            e, t0, ep = (int(v) for v in start_obs[i])
            assert e == int(ids[i])
            # the j-th action is the expert's at step t0 + j k of the same episode (dt = k env steps)
            want = torch.stack([tag_expert(torch.tensor([[e, t0 + j * stride, ep]], dtype=torch.float32))[0]
                                for j in range(horizon)])
            torch.testing.assert_close(acts[i], want, rtol=0, atol=0)
            seen.add((e, ep, t0))
        obs_td, _, dones, _ = env.step(act)
        obs = obs_td["policy"]
        windows.reset(torch.nonzero(dones).flatten())
    assert seen == expected_windows(lengths, steps, horizon, stride)


def test_window_across_a_reset_is_dropped(scripted_env, tag_expert):
    env = scripted_env([6])  # H = 5, k = 2 needs 9 steps of one episode: a 6-step episode gives none
    windows = SlidingWindows(1, 3, 28, horizon=5, stride=2)
    obs = env.get_observations()["policy"]
    emitted = 0
    for _ in range(30):
        ids, _, _ = windows.push(obs, tag_expert(obs))
        emitted += len(ids)
        obs_td, _, dones, _ = env.step(torch.zeros(1, 28))
        obs = obs_td["policy"]
        windows.reset(torch.nonzero(dones).flatten())
    assert emitted == 0


def test_dt_0p04_is_every_second_env_step():
    assert EncodingSection(dt=0.04, horizon=5).stride(0.02) == 2
    assert EncodingSection(dt=0.02, horizon=5).stride(0.02) == 1
    with pytest.raises(ValueError, match="not a multiple of the env step 0.02"):
        EncodingSection(dt=0.03, horizon=5).stride(0.02)
    with pytest.raises(ValueError, match="not a multiple"):
        EncodingSection(dt=0.01, horizon=5).stride(0.02)


def test_collect_labels_and_count(scripted_env, tag_expert):
    env = scripted_env([11, 8, 20])
    cfg = EncodingConfig("discrete", "first", 3)
    rows = []
    info = collect(env, tag_expert, lambda a: encode(a, cfg), 50, cfg, 2,
                   lambda o, lab: rows.append((o, lab)), flush_every=7)
    obs = torch.cat([o for o, _ in rows])
    labels = torch.cat([lab for _, lab in rows])
    assert info["datapoints"] == len(obs) == 50
    for o, lab in zip(obs, labels):
        e, t0, ep = (int(v) for v in o)
        acts = torch.stack([tag_expert(torch.tensor([[e, t0 + 2 * j, ep]], dtype=torch.float32))[0] for j in range(3)])
        torch.testing.assert_close(lab, encode(acts, cfg), rtol=0, atol=0)


def test_dagger_applies_the_beta_mixture(scripted_env, tag_expert):
    env = scripted_env([50, 50])
    cfg = EncodingConfig("first", "first", 2)

    def student(obs):
        return torch.full((obs.shape[0], 28), -3.0)

    collect(env, tag_expert, lambda a: encode(a, cfg), 10, cfg, 1, lambda o, lab: None, beta_value=0.25,
            student=student)
    obs0 = scripted_env([50, 50]).get_observations()["policy"]
    torch.testing.assert_close(env.applied[0], 0.25 * tag_expert(obs0) + 0.75 * -3.0)


def test_beta_schedules():
    exp = SelectorSection("exponential", 0.6)
    assert [beta(exp, i) for i in range(4)] == pytest.approx([1.0, 0.6, 0.36, 0.216])
    ind = SelectorSection("indicator")
    assert [beta(ind, i) for i in range(3)] == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="alpha"):
        SelectorSection("exponential", 1.0)
    with pytest.raises(ValueError, match="allowed"):
        SelectorSection("linear", 0.5)
