"""Reward manager: r = sum_i w_i r_i dt (IsaacLab convention: weights are per second).

Weights are mutable (``self.weights``) so a curriculum can switch terms on. Episode sums per term
are logged at reset as ``Episode_Reward/<term>`` (sum over the episode / episode length in s, a 0-dim tensor).
A term function with a ``parts(env) -> {name: (B,)}`` attribute (its last value split into parts that sum to it)
has each part logged the same way, weighted, as ``Episode_Reward/<term>/<part>``.
"""

from __future__ import annotations

from typing import Any

import torch

from dls_quadruped.core.compile import Fused
from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import rewards as reward_mdp


def resolve_rewards(task: TaskConfig) -> list[Term]:
    """The ``rewards`` section checked and resolved (``weight``: a finite number, not a bool)."""
    return resolve_terms(task, "rewards", reward_mdp, {"weight": ...})


class RewardManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.terms = resolve_rewards(task)
        self.weights = {t.name: float(t.extra["weight"]) for t in self.terms}
        self.episode_sums = {t.name: torch.zeros(env.num_envs, device=env.device) for t in self.terms}
        self.part_sums: dict[str, torch.Tensor] = {}
        """``<term>/<part>`` -> (B,) episode sums of the parts of the terms that split their value (``parts``)."""
        self.step_reward = torch.zeros(env.num_envs, len(self.terms), device=env.device)
        # compiled with scene.compile (a weight a curriculum switches on recompiles once)
        self._compute = Fused(self._compute_eager, getattr(env, "compile", False), "RewardManager.compute")

    def compute(self, dt: float) -> torch.Tensor:
        """(B,) total reward of this policy step; non-finite term values count as 0 (and are logged)."""
        return self._compute(dt)

    def _compute_eager(self, dt: float) -> torch.Tensor:
        total = torch.zeros(self.env.num_envs, device=self.env.device)
        for i, term in enumerate(self.terms):
            w = self.weights[term.name]
            if w == 0.0:
                self.step_reward[:, i] = 0.0
                continue
            value = term(self.env).float()
            value = torch.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0)
            r = value * w * dt
            self.step_reward[:, i] = r
            self.episode_sums[term.name] += r
            total += r
            split = getattr(term.func, "parts", None)
            for part, v in (split(self.env) if split is not None else {}).items():
                key = f"{term.name}/{part}"
                if key not in self.part_sums:
                    self.part_sums[key] = torch.zeros_like(r)
                self.part_sums[key] += torch.nan_to_num(v.float(), nan=0.0, posinf=0.0, neginf=0.0) * w * dt
        return total

    def episode_fraction(self, name: str, env_ids: torch.Tensor) -> float:
        """Mean episode sum of ``name`` over ``env_ids`` divided by its maximum weight x episode length
        (1.0 = a bounded kernel at its maximum for the whole episode)."""
        if name not in self.weights:
            raise KeyError(f"unknown reward term {name!r}; allowed: {sorted(self.weights)}")
        w = self.weights[name]
        if w == 0.0 or len(env_ids) == 0:
            return 0.0
        return float(self.episode_sums[name][env_ids].mean() / (w * self.env.max_episode_length_s))

    def reset(self, env_ids: torch.Tensor) -> dict[str, torch.Tensor]:
        """Episode sums of ``env_ids`` (mean over them / episode length [s]) as 0-dim tensors on the env's device
        (not read back here: the logger does that, once per iteration), then cleared."""
        logs = {}
        for name, s in (self.episode_sums | self.part_sums).items():
            logs[f"Episode_Reward/{name}"] = s[env_ids].mean() / self.env.max_episode_length_s
            s.index_fill_(0, env_ids, 0.0)
        return logs

    def state_dict(self) -> dict[str, Any]:
        """``{"weights": {term: weight}}``: the weights as a curriculum left them."""
        return {"weights": dict(self.weights)}

    def check_state_dict(self, state: dict[str, Any]) -> None:
        if set(state["weights"]) != set(self.weights):
            raise ValueError(f"checkpoint reward terms {sorted(state['weights'])} != task's {sorted(self.weights)}")

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.check_state_dict(state)
        self.weights.update(state["weights"])

    def summary(self) -> str:
        rows = [(t.name, t.func.__name__, self.weights[t.name], t.params) for t in self.terms]
        return format_table("rewards", ("term", "function", "weight", "params"), rows)
