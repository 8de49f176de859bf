"""Event manager: terms run at ``startup`` (once), at ``reset`` (for the reset envs) or on an
``interval`` (per-env timer drawn from ``interval_s`` [s], e.g. pushes every 8-12 s; as in IsaacLab,
a reset env draws a fresh timer, so an episode's push times do not depend on the one before).
Timers come from the env's episode schedule (stream ``interval/<term>``). Terms act on (B,) bool masks of robots
(``envs/mdp/events.py``): static shapes, no host read."""

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
    terms = resolve_terms(task, "events", event_mdp, {"mode": ..., "interval_s": None}, positional=("env", "env_mask"))
    for t in terms:
        key = f"events.{t.name}"
        if t.extra["mode"] not in MODES:
            raise task.error(f"{key}.mode", f"unknown mode {t.extra['mode']!r}; allowed: {list(MODES)}")
        if t.extra["mode"] == "interval" and t.extra["interval_s"] is None:
            raise task.error(f"{key}.interval_s", "interval events need interval_s: [low, high] seconds")
    return terms


class EventManager(ManagerBase):
    """Runs the event terms by (B,) bool masks of the robots they act on (``envs/mdp/events.py``): every robot's
    values are computed and the masked ones kept, so no step reads back which robots reset or are pushed."""

    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        # placement first: VecSim.reset clears the base wrench, so e.g. external_wrench must come after it
        self.terms = sorted(resolve_events(task), key=lambda t: t.func is not event_mdp.reset_robot)
        self.timers: dict[str, torch.Tensor] = {}
        """Per interval term, (B,) seconds [s] until each robot's next event."""
        for t in self._interval_terms():
            self.timers[t.name] = torch.zeros(env.num_envs, device=env.device)
        self.restart_timers()

    def _all(self) -> torch.Tensor:
        return torch.ones(self.env.num_envs, dtype=torch.bool, device=self.env.device)

    def _redraw(self, term: Term, env_mask: torch.Tensor) -> None:
        """Fresh timers of interval ``term`` for the robots of ``env_mask``, inside ``schedule.only(env_mask)``."""
        lo, hi = term.extra["interval_s"]
        ids = torch.arange(self.env.num_envs, device=self.env.device)
        fresh = self.env.schedule.uniform(ids, (), float(lo), float(hi), stream=f"interval/{term.name}")
        self.timers[term.name].copy_(torch.where(env_mask, fresh, self.timers[term.name]))

    def _interval_terms(self) -> list[Term]:
        return [t for t in self.terms if t.extra["mode"] == "interval"]

    def restart_timers(self, env_mask: torch.Tensor | None = None) -> None:
        """Draw fresh interval timers for the robots of ``env_mask`` (B,) bool (default: every env)."""
        env_mask = self._all() if env_mask is None else env_mask
        with self.env.schedule.only(env_mask):
            for t in self._interval_terms():
                self._redraw(t, env_mask)

    def apply(self, mode: str, env_mask: torch.Tensor | None = None, dt: float = 0.0) -> None:
        """Run the terms of ``mode``: ``startup`` on every env, ``reset`` on the robots of ``env_mask`` (B,) bool
        (their interval timers are redrawn too), ``interval`` after advancing every timer by ``dt`` [s] on the robots
        whose timer ran out (their timers redrawn). Each term's draws count only for the robots it acts on."""
        if mode == "interval":
            for t in self._interval_terms():
                self.timers[t.name] -= dt
                due = self.timers[t.name] <= 0.0
                with self.env.schedule.only(due):
                    self._redraw(t, due)
                    t(self.env, due)
            return
        env_mask = self._all() if env_mask is None or mode == "startup" else env_mask
        with self.env.schedule.only(env_mask):
            for t in self.terms:
                if t.extra["mode"] == mode:
                    t(self.env, env_mask)
            if mode == "reset":
                for t in self._interval_terms():
                    self._redraw(t, env_mask)

    def summary(self) -> str:
        rows = [(t.name, t.func.__name__, t.extra["mode"], t.extra["interval_s"] or "", t.params) for t in self.terms]
        return format_table("events", ("term", "function", "mode", "interval_s", "params"), rows)
