"""Reward manager: r = sum_i w_i r_i dt (IsaacLab convention: weights are per second).

Weights are mutable (``self.weights``) so a curriculum can switch terms on. Each write also lands in a device
tensor the (compiled) compute reads, so switching a weight neither recompiles nor uploads per step. Episode sums
per term are logged at reset as ``Episode_Reward/<term>`` (sum over the episode / episode length in s, a 0-dim
tensor). A term function with a ``parts(env) -> {name: (B,)}`` attribute (its last value split into parts that sum
to it) has each part logged the same way, weighted, as ``Episode_Reward/<term>/<part>``.
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


class Weights(dict):
    """``{term: weight}`` whose every write is mirrored into ``tensor`` (float32, (terms,), on the env's device).

    A term whose weight is 0 when the manager is built is not computed (it cannot reward anything) until a write
    makes it non-zero; ``on_activate`` is then called once (the manager rebuilds its compiled compute)."""

    def __init__(self, names: list[str], values: list[float], device: torch.device, on_activate) -> None:
        super().__init__(zip(names, values))
        self.index = {n: i for i, n in enumerate(names)}
        self.tensor = torch.tensor(values, dtype=torch.float32, device=device)
        self.active = tuple(i for i, v in enumerate(values) if v != 0.0)
        self._on_activate = on_activate

    def __setitem__(self, name: str, value: float) -> None:
        if name not in self.index:
            raise KeyError(f"unknown reward term {name!r}; allowed: {sorted(self.index)}")
        value = float(value)
        super().__setitem__(name, value)
        i = self.index[name]
        self.tensor[i] = value  # in place: the compiled compute keeps reading the same storage
        if value != 0.0 and i not in self.active:
            self.active = tuple(sorted((*self.active, i)))
            self._on_activate()

    def update(self, other=(), **kwargs) -> None:
        for name, value in dict(other, **kwargs).items():
            self[name] = value


class RewardManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.terms = resolve_rewards(task)
        self.weights = Weights([t.name for t in self.terms], [float(t.extra["weight"]) for t in self.terms],
                               env.device, self._build_compute)
        self.episode_sums = {t.name: torch.zeros(env.num_envs, device=env.device) for t in self.terms}
        self.part_sums: dict[str, torch.Tensor] = {}
        """``<term>/<part>`` -> (B,) episode sums of the parts of the terms that split their value (``parts``)."""
        self.step_reward = torch.zeros(env.num_envs, len(self.terms), device=env.device)
        self._build_compute()

    def _build_compute(self) -> None:
        # compiled with scene.compile; the weights are a tensor it reads, so a curriculum switch does not recompile
        self._compute = Fused(self._compute_eager, getattr(self.env, "compile", False), "RewardManager.compute")

    def compute(self, dt: float) -> torch.Tensor:
        """(B,) total reward of this policy step; non-finite term values count as 0 (and are logged)."""
        return self._compute(dt)

    def _compute_eager(self, dt: float) -> torch.Tensor:
        total = torch.zeros(self.env.num_envs, device=self.env.device)
        w = self.weights.tensor
        active = self.weights.active
        for i, term in enumerate(self.terms):
            if i not in active:  # weight 0 since the manager was built
                self.step_reward[:, i] = 0.0
                continue
            value = term(self.env).float()
            value = torch.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0)
            r = value * w[i] * dt  # a weight switched to 0 by a curriculum adds +-0
            self.step_reward[:, i] = r
            self.episode_sums[term.name] += r
            total += r
            split = getattr(term.func, "parts", None)
            for part, v in (split(self.env) if split is not None else {}).items():
                key = f"{term.name}/{part}"
                if key not in self.part_sums:
                    self.part_sums[key] = torch.zeros_like(r)
                self.part_sums[key] += torch.nan_to_num(v.float(), nan=0.0, posinf=0.0, neginf=0.0) * w[i] * dt
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
