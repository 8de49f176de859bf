"""Event manager: terms run at ``startup`` (once), at ``reset`` (for the reset envs) or on an
``interval`` (per-env timer drawn from ``interval_s`` [s], e.g. pushes every 8-12 s; as in IsaacLab,
a reset env draws a fresh timer, so an episode's push times do not depend on the one before).
Timers come from the env's episode schedule (stream ``interval/<term>``)."""

from __future__ import annotations

import torch

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import events as event_mdp

MODES = ("startup", "reset", "interval")


def resolve_events(task: TaskConfig) -> list[Term]:
    """The ``events`` section checked and resolved: known modes, ``interval_s`` on interval events."""
    terms = resolve_terms(task, "events", event_mdp, {"mode": ..., "interval_s": None}, positional=("env", "env_ids"))
    for t in terms:
        key = f"events.{t.name}"
        if t.extra["mode"] not in MODES:
            raise task.error(f"{key}.mode", f"unknown mode {t.extra['mode']!r}; allowed: {list(MODES)}")
        if t.extra["mode"] == "interval" and t.extra["interval_s"] is None:
            raise task.error(f"{key}.interval_s", "interval events need interval_s: [low, high] seconds")
    return terms


class EventManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        # placement first: VecSim.reset clears the base wrench, so e.g. external_wrench must come after it
        self.terms = sorted(resolve_events(task), key=lambda t: t.func is not event_mdp.reset_robot)
        self.timers: dict[str, torch.Tensor] = {}
        self.restart_timers()

    def _draw(self, term, env_ids: torch.Tensor) -> torch.Tensor:
        lo, hi = term.extra["interval_s"]
        return self.env.schedule.uniform(env_ids, (), float(lo), float(hi), stream=f"interval/{term.name}")

    def restart_timers(self, env_ids: torch.Tensor | None = None) -> None:
        """Draw fresh interval timers for ``env_ids`` (default: every env)."""
        if env_ids is None:
            env_ids = torch.arange(self.env.num_envs, device=self.env.device)
        for t in self.terms:
            if t.extra["mode"] == "interval":
                if t.name not in self.timers:
                    self.timers[t.name] = torch.zeros(self.env.num_envs, device=self.env.device)
                self.timers[t.name][env_ids] = self._draw(t, env_ids)

    def due(self, dt: float, resetting: torch.Tensor) -> dict[str, torch.Tensor]:
        """The (B,) bool masks of the robots each interval term fires on at this step's ``apply("interval", dt)``,
        known before ``resetting`` robots reset (so that the env reads them with its reset mask, in one host read).

        A robot not reset fires iff ``timer - dt <= 0`` (apply's own float operation on the same timer); a reset
        robot draws a fresh timer of at least ``interval_s[0]``, so it cannot fire when ``interval_s[0] > dt``.
        Terms with ``interval_s[0] <= dt`` are left out: ``apply`` then finds their robots itself (one more read).
        """
        return {t.name: (self.timers[t.name] - dt <= 0.0) & ~resetting for t in self.terms
                if t.extra["mode"] == "interval" and float(t.extra["interval_s"][0]) - dt > 1e-6}

    def apply(self, mode: str, env_ids: torch.Tensor | None = None, dt: float = 0.0,
              due: dict[str, torch.Tensor] | None = None) -> None:
        """Run the terms of ``mode``; ``env_ids`` for reset, ``dt`` [s] advances interval timers; ``due``: for
        interval terms, the ids of the robots they fire on, from :meth:`due`'s masks (the others are found here)."""
        all_ids = torch.arange(self.env.num_envs, device=self.env.device)
        for t in self.terms:
            if t.extra["mode"] != mode:
                continue
            if mode == "interval":
                timer = self.timers[t.name]
                timer -= dt
                ids = due[t.name] if due is not None and t.name in due else torch.nonzero(timer <= 0.0).flatten()
                if len(ids):
                    timer[ids] = self._draw(t, ids)
                    t(self.env, ids)
            elif mode == "startup":
                t(self.env, all_ids)
            elif env_ids is not None and len(env_ids):
                t(self.env, env_ids)
        if mode == "reset" and env_ids is not None and len(env_ids):
            self.restart_timers(env_ids)

    def summary(self) -> str:
        rows = [(t.name, t.func.__name__, t.extra["mode"], t.extra["interval_s"] or "", t.params) for t in self.terms]
        return format_table("events", ("term", "function", "mode", "interval_s", "params"), rows)
