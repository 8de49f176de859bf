"""Command manager: one velocity command (B, 3) resampled every U(resampling_time_s) seconds and at reset.

Task file::

    commands:
      base_velocity:
        func: uniform_velocity
        resampling_time_s: [10.0, 10.0]
        params: {lin_vel_x: [-1, 1], lin_vel_y: [-1, 1], ang_vel_z: [-1, 1]}
"""

from __future__ import annotations

import torch

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import Term, format_table, resolve_terms
from dls_quadruped.envs.mdp import commands as cmd_mdp


def resolve_command(task: TaskConfig) -> Term:
    """The ``commands`` section checked and resolved: exactly one term; ``resampling_time_s`` ordered, >= 0."""
    terms = resolve_terms(task, "commands", cmd_mdp, {"resampling_time_s": [10.0, 10.0]},
                          positional=("env", "env_ids"))
    if len(terms) != 1:
        raise task.error("commands", f"exactly one command term is supported, got {[t.name for t in terms]}")
    return terms[0]


class CommandManager:
    def __init__(self, task: TaskConfig, env):
        self.env = env
        self.term = resolve_command(task)
        self.params = self.term.params  # mutable: curricula widen the ranges
        self.resampling_time_s = tuple(float(x) for x in self.term.extra["resampling_time_s"])
        self.command = torch.zeros(env.num_envs, 3, device=env.device)
        self.time_left = torch.zeros(env.num_envs, device=env.device)

    def resample(self, env_ids: torch.Tensor) -> None:
        if len(env_ids) == 0:
            return
        self.command[env_ids] = self.term.func(self.env, env_ids, **self.params).to(self.command)
        lo, hi = self.resampling_time_s
        self.time_left[env_ids] = torch.empty(len(env_ids), device=self.env.device).uniform_(lo, hi)

    def compute(self, dt: float) -> None:
        """Advance the timers by the policy step and resample the expired commands."""
        self.time_left -= dt
        self.resample(torch.nonzero(self.time_left <= 0.0).flatten())

    def reset(self, env_ids: torch.Tensor) -> dict[str, float]:
        self.resample(env_ids)
        return {}

    def summary(self) -> str:
        return format_table("commands", ("term", "function", "resampling_time_s", "params"),
                            [(self.term.name, self.term.func.__name__, self.resampling_time_s, self.params)])
