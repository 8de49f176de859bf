"""Curriculum manager: terms ``term(env, env_mask, **params) -> Tensor`` run at every step for the envs being reset,
a (B,) bool mask (before the other managers clear their episode data), inside ``schedule.only(env_mask)``; their
0-dim values are logged as ``Curriculum/<term>`` without a host read (the env's episode log is read once per
iteration); ``values_as_floats`` and checkpoints convert."""

from __future__ import annotations

import copy
from typing import Any

import torch

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import curriculum as cur_mdp


def resolve_curriculum(task: TaskConfig) -> list[Term]:
    """The ``curriculum`` section checked and resolved."""
    return resolve_terms(task, "curriculum", cur_mdp, {}, positional=("env", "env_mask"))


REWARD_NAME_PARAMS = ("reward_term", "terms")
"""Curriculum parameters that name reward terms (a name, or a list of names)."""


def check_reward_names(task: TaskConfig, terms: list[Term], rewards: list[str]) -> None:
    """Every reward term a curriculum term names must be in the task's ``rewards``: a typo or a removed
    reward fails when the env is built, naming the file, the key and the rewards there are.

    Raises:
        ConfigError: an unknown reward name.
    """
    for t in terms:
        for key in REWARD_NAME_PARAMS:
            value = t.params.get(key)
            names = [value] if isinstance(value, str) else list(value) if isinstance(value, (list, tuple)) else []
            unknown = [n for n in names if n not in rewards]
            if unknown:
                raise task.error(f"curriculum.{t.name}.params.{key}",
                                 f"unknown reward term(s) {unknown}; the task's rewards are {sorted(rewards)}")


class CurriculumManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.terms = resolve_curriculum(task)
        check_reward_names(task, self.terms, list(env.reward_manager.weights))
        self.state: dict = {}
        self.values: dict[str, float | torch.Tensor] = {}

    def start(self) -> None:
        """Build-time call with no env (terms set their initial state)."""
        self.compute(torch.zeros(self.env.num_envs, dtype=torch.bool, device=self.env.device))

    def compute(self, env_mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """Run every term for the envs of ``env_mask`` (B,) bool; returns ``{"Curriculum/<term>": 0-dim value}``."""
        with self.env.schedule.only(env_mask):
            for t in self.terms:
                self.values[t.name] = t(self.env, env_mask)
        command_manager = getattr(self.env, "command_manager", None)
        if command_manager is not None:  # a range a term widened reaches the samplers before the reset resamples
            command_manager.sync_ranges()
        return {f"Curriculum/{k}": v for k, v in self.values.items()}

    def values_as_floats(self) -> dict[str, float]:
        """The last value of each term as a Python float (reads tensors back: not for the step)."""
        return {k: float(v) for k, v in self.values.items()}

    def state_dict(self) -> dict[str, Any]:
        """``{"state": terms' state, "values": last value per term}``, with Python numbers for 0-dim tensors (a
        device flag is read back here, once per checkpoint)."""
        return {"state": copy.deepcopy(_to_host(self.state)), "values": self.values_as_floats()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.check_state_dict(state)
        self.state.clear()
        self.state.update(copy.deepcopy(state["state"]))
        self.values.update(state["values"])

    def summary(self) -> str:
        return format_table("curriculum", ("term", "function", "params"),
                            [(t.name, t.func.__name__, t.params) for t in self.terms])


def _to_host(value: Any) -> Any:
    """``value`` with every 0-dim tensor inside (dicts, lists) replaced by its Python number."""
    if isinstance(value, torch.Tensor) and value.dim() == 0:
        return value.item()
    if isinstance(value, dict):
        return {k: _to_host(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_to_host(v) for v in value)
    return value
