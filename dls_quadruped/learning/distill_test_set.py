"""Held-out MSE test set from the expert's own whole episodes (thesis 7.2.1, eq. 7.2.1).

Why not the first windows after a reset: every robot starts together, so the first ~1000 windows
of a 64-robot env are the first ~0.6 s of its episodes (the start-up, not walking). Here the expert
drives ``E`` scheduled 15 s episodes of the task (its command distribution, pushes and noise;
episode keys ``0 .. E-1`` of ``seed``), every observation and raw expert action is recorded until
the episode ends (time-out or fall), and label windows are cut afterwards at start steps spread
over every phase of every episode. The recording is encoding-free: one recording serves every row
of a table, and the *same* start steps (hence the same test states) are used for every encoding,
horizon H and spacing k, as long as the window fits (``span = (H - 1) k + 1`` steps within the
episode for the largest span of the table).

Start steps are stratified over all valid (episode, step) pairs in episode order: pair j of the M
valid ones lies in stratum ``floor(j N / M)``, and one pair is drawn per stratum with a fixed seed,
so N starts cover every episode in proportion to its valid length and every phase of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dls_quadruped.envs.recorder import EpisodeRecord, record


@dataclass
class ExpertEpisodes:
    """The expert's recorded episodes, episode-major (cut into windows by :func:`cut_windows`).

    Attributes:
        obs: (E, T, obs_dim) float32 observation at each step (zeros after the episode's end).
        actions: (E, T, act_dim) float32 raw expert action at that observation.
        length: (E,) long, steps of each episode (T for a time-out; fewer after a fall).
        seed: schedule seed the episodes were played with.
    """

    obs: torch.Tensor
    actions: torch.Tensor
    length: torch.Tensor
    seed: int

    @classmethod
    def from_record(cls, rec: EpisodeRecord, envs: slice, seed: int) -> ExpertEpisodes:
        """The episodes of the envs ``envs`` in a :func:`envs.recorder.record` run that captured exactly them
        (``capture=envs``): its (T, C, ...) inputs and actions, zero where not ``active``, made episode-major."""
        active = rec.active[:, envs]

        def episode_major(values: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(rec.masked(values, active, fill=0.0)).float().transpose(0, 1).contiguous()

        return cls(episode_major(rec.obs), episode_major(rec.actions), torch.from_numpy(rec.length[envs].copy()),
                   int(seed))


@torch.no_grad()
def record_expert_episodes(env, expert, seed: int, episodes: int, obs_group: str = "policy") -> ExpertEpisodes:
    """Play scheduled episodes 0 .. ``episodes`` - 1 of ``seed`` with the expert and record them
    (``envs.recorder.record``, under ``no_grad``: the env goes on collecting afterwards).

    Rounds of ``env.num_envs`` robots: in round r robot i plays key ``r num_envs + i`` (the last
    round's extra robots play keys beyond the set, not recorded).

    Args:
        env: ``LocomotionEnv`` (``reset(seed=..., episode_keys=...)``).
        expert: (B, obs_dim) -> (B, act_dim) raw actions.
        seed: schedule seed (distinct from training and SP seeds: the set is held out).
        episodes: E.
    """
    n = env.num_envs
    rounds: list[ExpertEpisodes] = []
    for first in range(0, episodes, n):
        env.reset(seed=seed, episode_keys=torch.arange(first, first + n, device=env.device))
        rec = record(env, policy=expert, obs_group=obs_group, capture=True, stop_when_all_ended=True, no_grad=True,
                     desc=f"test-set episodes {first}-{first + n - 1}")
        rounds.append(ExpertEpisodes.from_record(rec, slice(None), seed))
    obs, act, length = (torch.cat([getattr(r, name) for r in rounds])[:episodes]
                        for name in ("obs", "actions", "length"))
    return ExpertEpisodes(obs, act, length, int(seed))


def window_starts(length: torch.Tensor, span: int, count: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Stratified start steps of ``count`` windows of ``span`` steps over whole episodes.

    Args:
        length: (E,) steps of each episode; episode e has ``max(0, length[e] - span + 1)`` valid starts.
        span: steps a window covers, ``(H - 1) k + 1`` of the largest horizon it must serve.
        count: N windows (at most the M valid starts).
        seed: fixed seed of the draw within each stratum.

    Returns:
        episode (N,), start step (N,), both long, in episode order.

    Raises:
        ValueError: fewer valid starts than ``count``.
    """
    valid = (length.long() - span + 1).clamp(min=0)
    total = int(valid.sum())
    if total < count:
        raise ValueError(f"{total} valid window starts of span {span} in {len(length)} episodes; {count} asked")
    rng = np.random.default_rng(seed)
    # stratum i holds the pairs j with floor(j N / M) = i, i.e. j in [ceil(i M / N), ceil((i+1) M / N))
    lo = -(-np.arange(count) * total // count)
    hi = -(-(np.arange(count) + 1) * total // count)
    j = torch.from_numpy(lo + (rng.random(count) * (hi - lo)).astype(np.int64))
    ends = torch.cumsum(valid, 0)  # pair j belongs to the first episode whose cumulative count exceeds j
    episode = torch.searchsorted(ends, j, right=True)
    start = j - (ends[episode] - valid[episode])
    return episode, start


def cut_windows(record: ExpertEpisodes, episode: torch.Tensor, start: torch.Tensor, horizon: int,
                stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Observations at the starts and the expert's H actions k steps apart from there.

    Returns:
        obs (N, obs_dim), actions (N, H, act_dim) (steps start, start + k, ..., start + (H-1) k).

    Raises:
        ValueError: a window runs past the end of its episode.
    """
    steps = start[:, None] + torch.arange(horizon) * stride  # (N, H)
    if bool((steps[:, -1] >= record.length[episode]).any()):
        raise ValueError(f"a window of H={horizon}, k={stride} runs past its episode's end")
    return record.obs[episode, start], record.actions[episode[:, None], steps]
