"""Termination manager: dones = any term; ``time_out`` terms are reported separately as time-outs.

Besides the task's terms, robots the env hands in as ``nonfinite_action`` (their action had a NaN
or an infinity and was replaced by zeros) are terminated and counted as
``Episode_Termination/nonfinite_action``, as a diverged simulation is.
"""

from __future__ import annotations

import torch

from dls_quadruped.core.compile import fused_method
from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import terminations as term_mdp

NONFINITE_ACTION = "nonfinite_action"


def resolve_terminations(task: TaskConfig) -> list[Term]:
    """The ``terminations`` section checked and resolved (``time_out``: a bool)."""
    return resolve_terms(task, "terminations", term_mdp, {"time_out": False})


class TerminationManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.terms = resolve_terminations(task)
        n = env.num_envs
        self.terminated = torch.zeros(n, dtype=torch.bool, device=env.device)
        self.time_outs = torch.zeros(n, dtype=torch.bool, device=env.device)
        self.term_dones = {t.name: torch.zeros(n, dtype=torch.bool, device=env.device) for t in self.terms}
        self.term_dones[NONFINITE_ACTION] = torch.zeros(n, dtype=torch.bool, device=env.device)

    def compute(self, nonfinite_action: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) bool dones = terminated | time_outs (a robot that fails on its last step is terminated).

        Args:
            nonfinite_action: (B,) bool, robots whose action was not finite (terminated).
        """
        return self._compute(nonfinite_action)

    @fused_method("TerminationManager.compute")
    def _compute(self, nonfinite_action: torch.Tensor | None = None) -> torch.Tensor:
        self.terminated[:] = False
        self.time_outs[:] = False
        bad = self.term_dones[NONFINITE_ACTION]
        bad[:] = False if nonfinite_action is None else nonfinite_action
        self.terminated |= bad
        for t in self.terms:
            d = t(self.env).bool()
            self.term_dones[t.name][:] = d
            if t.extra["time_out"]:
                self.time_outs |= d
            else:
                self.terminated |= d
        self.time_outs &= ~self.terminated
        return self.terminated | self.time_outs

    def reset(self, env_mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """How many of the envs of ``env_mask`` (B,) bool each term ended, as 0-dim float tensors on the env's device
        (not read back)."""
        return {f"Episode_Termination/{name}": (d & env_mask).float().sum() for name, d in self.term_dones.items()}

    def summary(self) -> str:
        rows = [(t.name, t.func.__name__, t.extra["time_out"], t.params) for t in self.terms]
        return format_table("terminations", ("term", "function", "time_out", "params"), rows)
