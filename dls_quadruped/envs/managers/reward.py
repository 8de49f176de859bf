"""Reward manager: r = sum_i w_i r_i dt (IsaacLab convention: weights are per second).

Weights are mutable (``self.weights``) so a curriculum can switch terms on. They live in a device tensor the
(compiled) compute reads, so switching a weight neither recompiles nor uploads per step, and a curriculum switches
them on the device (``Weights.switch``). Episode sums per term are logged at reset as ``Episode_Reward/<term>`` (sum
over the episode / episode length in s, mean over the reset envs, a 0-dim tensor). A term function with a
``parts(env) -> {name: (B,)}`` attribute (its last value split into parts that sum to it) has each part logged
the same way, weighted, as ``Episode_Reward/<term>/<part>``.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from typing import Any

import torch

from dls_quadruped.core.compile import fused_method
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


class Weights(MutableMapping):
    """``{term: weight}`` kept on the device: ``tensor`` (float32, (terms,)), which the (compiled) compute reads, and
    a float64 twin that holds the values as written (reading a weight by name reads it back: not for the step).

    A term whose weight is 0 when the manager is built is not computed (it cannot reward anything) until a write
    makes it non-zero; ``on_activate`` is then called once (the manager rebuilds its compiled compute). A curriculum
    switches weights on the device with :meth:`switch`, without a host read."""

    def __init__(self, names: list[str], values: list[float], device: torch.device, on_activate) -> None:
        self.index = {n: i for i, n in enumerate(names)}
        self.tensor = torch.tensor(values, dtype=torch.float32, device=device)
        self._values = torch.tensor(values, dtype=torch.float64, device=device)
        self.active = tuple(i for i, v in enumerate(values) if v != 0.0)
        self._on_activate = on_activate
        self._switches: dict[tuple[str, ...], tuple[torch.Tensor, torch.Tensor]] = {}

    def _check(self, name: str) -> int:
        if name not in self.index:
            raise KeyError(f"unknown reward term {name!r}; allowed: {sorted(self.index)}")
        return self.index[name]

    def __getitem__(self, name: str) -> float:
        return float(self._values[self._check(name)])

    def __setitem__(self, name: str, value: float) -> None:
        i, value = self._check(name), float(value)
        self.tensor[i] = value  # in place: the compiled compute keeps reading the same storage
        self._values[i] = value
        if value != 0.0 and i not in self.active:
            self.active = tuple(sorted((*self.active, i)))
            self._on_activate()

    def __delitem__(self, name: str) -> None:
        raise TypeError("reward weights cannot be removed; set a weight to 0 instead")

    def __iter__(self) -> Iterator[str]:
        return iter(self.index)

    def __len__(self) -> int:
        return len(self.index)

    def as_dict(self) -> dict[str, float]:
        """Every weight as a Python float (one host read)."""
        return dict(zip(self.index, self._values.tolist()))

    def switch(self, targets: dict[str, float], on: torch.Tensor) -> None:
        """Set the weights of ``targets`` to their values where ``on`` (a 0-dim bool on the device) holds, else to
        0, on the device (no host read; the index and values are uploaded once per set of names). A target that is
        not 0 activates its term on the first call, on the host (rebuilding the compute once)."""
        key = tuple(targets)
        if key not in self._switches:
            for name, value in targets.items():
                if value != 0.0 and self._check(name) not in self.active:
                    self[name] = value
            idx = torch.tensor([self._check(n) for n in key], device=self.tensor.device)
            self._switches[key] = idx, torch.tensor([float(targets[n]) for n in key], dtype=torch.float64,
                                                    device=self.tensor.device)
        idx, values = self._switches[key]
        chosen = torch.where(on, values, 0.0)
        self._values.index_copy_(0, idx, chosen)
        self.tensor.index_copy_(0, idx, chosen.float())


class RewardManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.terms = resolve_rewards(task)
        self.weights = Weights([t.name for t in self.terms], [float(t.extra["weight"]) for t in self.terms],
                               env.device, self._renew_compute)
        self.episode_sums = {t.name: torch.zeros(env.num_envs, device=env.device) for t in self.terms}
        self.part_sums: dict[str, torch.Tensor] = {}
        """``<term>/<part>`` -> (B,) episode sums of the parts of the terms that split their value (``parts``)."""
        self.step_reward = torch.zeros(env.num_envs, len(self.terms), device=env.device)

    def _renew_compute(self) -> None:
        """A term was activated: the compute is made anew (it reads which terms are active as Python values)."""
        RewardManager._compute.renew(self)

    def compute(self, dt: float) -> torch.Tensor:
        """(B,) total reward of this policy step; non-finite term values count as 0 (and are logged)."""
        return self._compute(dt)

    # compiled with scene.compile; the weights are a tensor it reads, so a curriculum switch does not recompile
    @fused_method("RewardManager.compute")
    def _compute(self, dt: float) -> torch.Tensor:
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

    def episode_fraction(self, name: str, env_mask: torch.Tensor) -> torch.Tensor:
        """0-dim, on the device: mean episode sum of ``name`` over the envs of ``env_mask`` (B,) bool divided by its
        weight x episode length (1.0 = a bounded kernel at its maximum for the whole episode); 0 when the mask is
        empty or the weight is 0."""
        i = self.weights._check(name)
        count = env_mask.sum()
        mean = torch.where(env_mask, self.episode_sums[name], 0.0).sum() / count.clamp(min=1)
        w = self.weights.tensor[i]
        return torch.where((w != 0.0) & (count > 0), mean / (w * self.env.max_episode_length_s), 0.0)

    def reset(self, env_mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """Episode sums of the envs of ``env_mask`` (B,) bool (mean over them / episode length [s]; 0 when none) as
        0-dim tensors on the env's device (not read back here: the env's episode log is read once per iteration),
        then cleared."""
        logs = {}
        count = env_mask.sum().clamp(min=1)
        for name, s in (self.episode_sums | self.part_sums).items():
            logs[f"Episode_Reward/{name}"] = torch.where(env_mask, s, 0.0).sum() / count / self.env.max_episode_length_s
            s.masked_fill_(env_mask, 0.0)
        return logs

    def state_dict(self) -> dict[str, Any]:
        """``{"weights": {term: weight}}``: the weights as a curriculum left them."""
        return {"weights": self.weights.as_dict()}

    def check_state_dict(self, state: dict[str, Any]) -> None:
        if set(state["weights"]) != set(self.weights):
            raise ValueError(f"checkpoint reward terms {sorted(state['weights'])} != task's {sorted(self.weights)}")

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.check_state_dict(state)
        self.weights.update(state["weights"])

    def summary(self) -> str:
        weights = self.weights.as_dict()
        rows = [(t.name, t.func.__name__, weights[t.name], t.params) for t in self.terms]
        return format_table("rewards", ("term", "function", "weight", "params"), rows)
