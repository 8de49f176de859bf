"""Stand-in envs for the distillation tests: scripted trajectories with known resets."""

from __future__ import annotations

import torch
from tensordict import TensorDict


class ScriptedEnv:
    """Env whose observation is (env id, step of its episode, episode number) and whose
    episode of env e lasts ``lengths[e]`` steps (then it resets); actions are recorded.

    The 'expert' :func:`tag_expert` returns an action that encodes (env, step, episode), so a
    window's actions name the steps they came from.
    """

    num_actions = 28
    step_dt = 0.02
    max_episode_length = 750
    device = "cpu"

    def __init__(self, lengths: list[int]):
        self.num_envs = len(lengths)
        self.lengths = torch.tensor(lengths)
        self.t_ep = torch.zeros(self.num_envs, dtype=torch.long)
        self.episode = torch.zeros(self.num_envs, dtype=torch.long)
        self.applied: list[torch.Tensor] = []

    def _obs(self) -> TensorDict:
        env_id = torch.arange(self.num_envs, dtype=torch.float32)
        obs = torch.stack([env_id, self.t_ep.float(), self.episode.float()], dim=1)
        return TensorDict({"policy": obs}, batch_size=[self.num_envs])

    def get_observations(self) -> TensorDict:
        return self._obs()

    def reset(self, seed=None, episode_keys=None):
        self.t_ep.zero_()
        return self._obs(), {}

    def step(self, actions: torch.Tensor):
        self.applied.append(actions.clone())
        self.t_ep += 1
        dones = self.t_ep >= self.lengths
        self.t_ep[dones] = 0
        self.episode[dones] += 1
        return self._obs(), torch.zeros(self.num_envs), dones.long(), {"time_outs": dones.clone()}


def tag_expert(obs: torch.Tensor) -> torch.Tensor:
    """(B, 3) -> (B, 28): entry i = 10000 episode + 100 env + step + i / 100, unique per (env, episode, step)."""
    tag = 10000.0 * obs[:, 2] + 100.0 * obs[:, 0] + obs[:, 1]
    return tag[:, None] + torch.arange(28, dtype=torch.float32) / 100.0


class LinearEnv:
    """s_{t+1} = A s_t + B a_t, no resets: with a = K s the expert's horizon is K (A + B K)^j s_t."""

    num_actions = 28
    step_dt = 0.02
    max_episode_length_s = 15.0
    max_episode_length = 750
    device = "cpu"

    def __init__(self, num_envs: int, A: torch.Tensor, B: torch.Tensor, seed: int = 0):
        self.num_envs, self.A, self.B = num_envs, A, B
        self.gen = torch.Generator().manual_seed(seed)
        self.s = torch.randn(num_envs, A.shape[0], generator=self.gen)

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": self.s.clone()}, batch_size=[self.num_envs])

    def reset(self, seed=None, episode_keys=None):
        self.s = torch.randn(self.num_envs, self.A.shape[0], generator=self.gen)
        return self.get_observations(), {}

    def step(self, actions: torch.Tensor):
        self.s = self.s @ self.A.T + actions @ self.B.T
        dones = torch.zeros(self.num_envs, dtype=torch.long)
        return self.get_observations(), torch.zeros(self.num_envs), dones, {"time_outs": dones.bool()}
