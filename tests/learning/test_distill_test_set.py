"""The MSE test set: window starts spread over whole episodes, windows cut from a recording."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.learning.collect import SlidingWindows
from dls_quadruped.learning.distill_test_set import (
    cut_windows,
    record_expert_episodes,
    window_starts,
)


def test_one_start_per_stratum_by_hand():
    """Two episodes of 10 steps, span 3: 8 valid starts each, M = 16 pairs in episode order; N = 4
    strata of 4 pairs: [0, 4) and [4, 8) of episode 0, then the same of episode 1."""
    episode, start = window_starts(torch.tensor([10, 10]), span=3, count=4, seed=0)
    assert episode.tolist() == [0, 0, 1, 1]
    assert 0 <= start[0] < 4 <= start[1] < 8 and 0 <= start[2] < 4 <= start[3] < 8


def test_all_valid_starts_when_count_is_their_number():
    """N = M: every (episode, start) pair exactly once; a 2-step episode (< span) gives none."""
    episode, start = window_starts(torch.tensor([6, 2, 5]), span=3, count=7, seed=3)
    assert list(zip(episode.tolist(), start.tolist())) == [(0, 0), (0, 1), (0, 2), (0, 3), (2, 0), (2, 1), (2, 2)]
    with pytest.raises(ValueError, match="7 valid window starts"):
        window_starts(torch.tensor([6, 2, 5]), span=3, count=8, seed=3)


def test_starts_cover_every_phase_of_15_s_episodes():
    """16 whole episodes of 750 steps, 1000 windows of span 29: each of the 16 episodes gets 62-63
    and every tenth of the valid range [0, 721] of every episode holds 6 or 7 of them (strata of
    721 x 16 / 1000 = 11.5 steps). The old set (first windows after a reset) held only starts 0-15."""
    length = torch.full((16,), 750)
    episode, start = window_starts(length, span=29, count=1000, seed=0)
    counts = torch.bincount(episode, minlength=16)
    assert counts.min() >= 62 and counts.max() <= 63
    assert start.min() >= 0 and start.max() <= 750 - 29
    for e in range(16):
        decile = torch.div(start[episode == e] * 10, 722, rounding_mode="floor")
        per = torch.bincount(decile, minlength=10)
        assert per.min() >= 5 and per.max() <= 8, (e, per.tolist())


def test_recorded_windows_are_the_collection_windows(scripted_env, tag_expert):
    """Cut from a recording, a window is what SlidingWindows emits for the same steps: the tag expert
    names (env, step, episode) in every action; a fall (episode of 7 steps) ends the recording."""
    env = scripted_env([7, 30, 30])
    env.max_episode_length = 20
    env.device = "cpu"
    rec = record_expert_episodes(env, tag_expert, seed=5, episodes=3)
    assert rec.length.tolist() == [7, 20, 20]
    episode, start = torch.tensor([0, 1, 2, 2]), torch.tensor([0, 3, 0, 10])
    obs, acts = cut_windows(rec, episode, start, horizon=3, stride=2)
    assert obs[:, 1].tolist() == [0.0, 3.0, 0.0, 10.0] and obs[:, 0].tolist() == [0.0, 1.0, 2.0, 2.0]
    assert acts[:, :, 0].tolist() == [[0, 2, 4], [103, 105, 107], [200, 202, 204], [210, 212, 214]]
    with pytest.raises(ValueError, match="past its episode"):
        cut_windows(rec, torch.tensor([0]), torch.tensor([3]), horizon=3, stride=2)  # steps 3, 5, 7 of 7
    ring = SlidingWindows(3, 3, 28, horizon=3, stride=2)  # the same windows, emitted online
    env2 = scripted_env([7, 30, 30])
    got = {}
    for _ in range(15):
        o = env2.get_observations()["policy"]
        ids, start_obs, a = ring.push(o, tag_expert(o))
        for i, so, aa in zip(ids.tolist(), start_obs, a):
            got[(i, int(so[1]))] = aa[:, 0].tolist()
        ring.reset(torch.nonzero(env2.step(torch.zeros(3, 28))[2]).flatten())
    assert got[(1, 3)] == acts[1, :, 0].tolist() and got[(2, 10)] == acts[3, :, 0].tolist()
