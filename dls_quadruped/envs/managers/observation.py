"""Observation manager: groups of terms, each concatenated into one (B, D) tensor, with per-term noise.

Task file::

    observations:
      policy:                      # group name (rsl-rl obs group)
        noise_scale: 1.0           # multiplies every term's noise (1 high, 1/3 low, 0 none)
        terms:
          base_lin_vel: {noise: 0.1}   # uniform noise U(-0.1, 0.1) x noise_scale
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from dls_quadruped.core.compile import fused_method
from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import observations as obs_mdp
from dls_quadruped.envs.value_checks import type_problem

GROUP_KEYS = ("noise_scale", "terms")


def resolve_groups(task: TaskConfig) -> tuple[dict[str, list[Term]], dict[str, float]]:
    """The ``observations`` section checked and resolved: ({group: terms}, {group: noise_scale >= 0})."""
    groups: dict[str, list[Term]] = {}
    noise_scale: dict[str, float] = {}
    for group, spec in task.section("observations").items():
        key = f"observations.{group}"
        if not isinstance(spec, dict) or set(spec) - set(GROUP_KEYS):
            raise task.error(key, f"a group is a mapping with keys {list(GROUP_KEYS)}")
        scale = spec.get("noise_scale", 1.0)
        problem = type_problem(scale, float) or (f"must be >= 0, got {scale}" if scale < 0 else None)
        if problem is not None:
            raise task.error(f"{key}.noise_scale", problem)
        noise_scale[group] = float(scale)
        groups[group] = resolve_terms(task, "observations", obs_mdp, {"noise": 0.0},
                                      entries=spec.get("terms") or {}, key_prefix=f"{key}.terms")
    return groups, noise_scale


class ObservationManager(ManagerBase):
    """Computes the observation groups as a TensorDict {group: (B, D_group)}."""

    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.groups, self.noise_scale = resolve_groups(task)
        self.dims: dict[str, dict[str, int]] = {}

    def compute(self) -> TensorDict:
        """Evaluate every group: concatenation of its terms plus U(-noise, noise) x noise_scale."""
        # the first call (the env's constructor) runs eagerly and records the terms' sizes; later ones are compiled
        # with scene.compile
        out = self._groups() if self.dims else self._groups.fn()
        return TensorDict(out, batch_size=[self.env.num_envs], device=self.env.device)

    @fused_method("ObservationManager.compute")
    def _groups(self) -> dict[str, torch.Tensor]:
        out = {}
        ids = torch.arange(self.env.num_envs, device=self.env.device)
        for group, terms in self.groups.items():
            parts = []
            for term in terms:
                value = term(self.env).reshape(self.env.num_envs, -1).float()
                noise = term.extra["noise"] * self.noise_scale[group]
                if noise > 0.0:  # from the episode schedule: the same noise in the same episode for any policy
                    value = value + self.env.schedule.uniform(ids, (value.shape[1],), -noise, noise,
                                                              stream=f"obs_noise/{group}/{term.name}")
                parts.append(value)
            if group not in self.dims:
                self.dims[group] = {t.name: p.shape[1] for t, p in zip(terms, parts)}
            out[group] = torch.cat(parts, dim=-1)
        return out

    def summary(self) -> str:
        rows = [(g, t.name, t.func.__name__, self.dims.get(g, {}).get(t.name, "?"),
                 t.extra["noise"] * self.noise_scale[g])
                for g, terms in self.groups.items() for t in terms]
        return format_table("observations", ("group", "term", "function", "dim", "noise"), rows)
