"""Datapoint collection from all vectorised envs at once (thesis Algorithms 3 and 4, Fig. 14-15).

A datapoint is ``(s_t, P(a_t, a_{t+k}, ..., a_{t+(H-1)k}))``: the observation at t and the expert's
raw actions at the states actually visited over the next H actions spaced dt = k env steps,
encoded with P (:func:`student.encode_labels`). Every env step, the expert (and, in DAgger, the
student) is called once on the whole batch; :class:`SlidingWindows` keeps the last (H-1)k+1
steps of every env in a ring and emits each window as soon as it is complete. A reset (time-out
or fall) restarts the env's count, so a window never spans two episodes. :func:`collect_slots`
does the same for several students at once, each driving its own slice of the robots. The env is
stepped by the one episode loop, ``envs.recorder.record`` (an episode length per call, its masks
unused: collection goes on through resets), which stops once the last window needed is taken,
before that step's action is applied.

Applied action (Algorithm 4, line 8): ``beta * a_exp + (1 - beta) * first_action(student)``;
beta = 1 is naive imitation (the expert drives) and skips the student.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import torch

from dls_quadruped.envs.recorder import record
from dls_quadruped.learning.distill_config import SelectorSection
from dls_quadruped.mpc.config import EncodingConfig

ActionFn = Callable[[torch.Tensor], torch.Tensor]
"""(B, 259) observations -> (B, 28) raw actions."""


def beta(selector: SelectorSection, epoch: int) -> float:
    """Policy selector beta(i) of eq. 5.2.1 at epoch i = 0, 1, ...: alpha^i or the indicator 1[i = 0]."""
    if selector.kind == "indicator":
        return 1.0 if epoch == 0 else 0.0
    return float(selector.alpha ** epoch)


class SlidingWindows:
    """Ring of the last ``span = (H-1) k + 1`` (observation, action) pairs of every env.

    Args:
        num_envs: B.
        obs_dim, act_dim: sizes of one observation and one action.
        horizon: H actions per window.
        stride: k env steps between two actions of a window (dt / step_dt).
    """

    def __init__(self, num_envs: int, obs_dim: int, act_dim: int, horizon: int, stride: int,
                 device: torch.device | str = "cpu"):
        if horizon < 1 or stride < 1:
            raise ValueError(f"horizon and stride must be >= 1, got {horizon}, {stride}")
        self.horizon, self.stride = horizon, stride
        self.span = (horizon - 1) * stride + 1
        self.obs = torch.zeros(self.span, num_envs, obs_dim, device=device)
        self.act = torch.zeros(self.span, num_envs, act_dim, device=device)
        self.count = torch.zeros(num_envs, dtype=torch.long, device=device)  # steps of the current episode held
        self.t = 0
        self._offsets = torch.arange(horizon, device=device) * stride

    def push(self, obs: torch.Tensor, act: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Record step t for every env and return the windows that end at t.

        Args:
            obs: (B, obs_dim) observation s_t; act: (B, act_dim) expert action at s_t.

        Returns:
            env_ids (n,), start observations (n, obs_dim) s_{t-span+1}, actions (n, H, act_dim) at
            steps t-span+1, t-span+1+k, ..., t, for the n envs whose last ``span`` steps are one episode.
        """
        slot = self.t % self.span
        self.obs[slot] = obs
        self.act[slot] = act
        self.count += 1
        self.t += 1
        ready = torch.nonzero(self.count >= self.span).flatten()
        first = self.t % self.span  # slot of step t - span + 1 (the oldest one held)
        slots = (first + self._offsets) % self.span
        acts = self.act[slots][:, ready].transpose(0, 1)  # (n, H, act_dim)
        return ready, self.obs[first, ready], acts

    def reset(self, env_ids: torch.Tensor) -> None:
        """Envs ``env_ids`` (n,) long start a new episode at the next push: their held steps are dropped."""
        self.count[env_ids.to(self.count.device)] = 0


class Progress:
    """One line every ``every_s`` seconds: what, how many of how many, rate, ETA."""

    def __init__(self, what: str, total: int, unit: str, every_s: float = 10.0, printer: Callable = print):
        self.what, self.total, self.unit, self.every_s, self.printer = what, total, unit, every_s, printer
        self.t0 = self._last = time.monotonic()

    def update(self, done: int, extra: str = "", force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < self.every_s:
            return
        self._last = now
        rate = done / max(now - self.t0, 1e-9)
        eta = (self.total - done) / rate if rate > 0 else math.inf
        self.printer(f"[distill] {self.what}: {done}/{self.total} {self.unit} ({rate:.0f}/s, ETA {eta:.0f} s)"
                     + (f" {extra}" if extra else ""), flush=True)

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.t0


@torch.no_grad()
def collect(env, expert: ActionFn, encode: Callable[[torch.Tensor], torch.Tensor], count: int,
            cfg: EncodingConfig, stride: int, sink: Callable[[torch.Tensor, torch.Tensor], None],
            beta_value: float = 1.0, student: ActionFn | None = None, obs_group: str = "policy",
            progress: Progress | None = None, flush_every: int = 8192) -> dict:
    """Step ``env`` until ``count`` datapoints were produced; hand them to ``sink(obs, labels)``.

    Args:
        env: ``LocomotionEnv``, or a stand-in with what ``envs.recorder.record`` steps (``num_envs``,
            ``num_actions``, ``step_dt``, ``max_episode_length``, ``get_observations``, ``step``,
            ``command_manager.command``).
        expert: raw expert action of a batch of observations.
        encode: (n, H, 28) actions -> (n, D) labels.
        count: datapoints to produce (the last batch is cut to it).
        stride: env steps between the actions of a horizon.
        sink: receives (obs, labels) chunks of about ``flush_every`` rows (e.g. ``DiskDataset.append``).
        beta_value: expert share of the applied action; < 1 needs ``student``.

    Returns:
        {"datapoints", "env_steps", "seconds", "resets"}.
    """
    info = collect_slots(env, expert, [encode], count, cfg.horizon, stride, lambda _, o, lab: sink(o, lab),
                         beta_value, student, obs_group, progress, flush_every)
    return {**info, "datapoints": info["datapoints"][0]}


@torch.no_grad()
def collect_slots(env, expert: ActionFn, encoders: list[Callable[[torch.Tensor], torch.Tensor]], count: int,
                  horizon: int, stride: int, sink: Callable[[int, torch.Tensor, torch.Tensor], None],
                  beta_value: float = 1.0, student: ActionFn | None = None, obs_group: str = "policy",
                  progress: Progress | None = None, flush_every: int = 8192,
                  windows: SlidingWindows | None = None) -> dict:
    """Like :func:`collect` for S students at once: the robots are S equal contiguous slots, slot s
    (robots ``[s B/S, (s+1) B/S)``) is driven by student s's share of ``student`` and its windows are
    encoded with ``encoders[s]`` and handed to ``sink(s, obs, labels)`` until it has ``count``.

    Args:
        student: (B, obs_dim) -> (B, 28) first actions of every slot's student on its own robots.
        windows: the ring of the previous call on this env, to go on where it stopped (its last step
            is the env's current observation, already pushed): no (H-1) k steps of warm-up per call.
            A window that spans two calls starts at a state reached under the previous call's
            applied action; its labels are the expert's actions at the states visited, as always.

    Returns:
        {"datapoints" (per slot), "env_steps", "seconds", "resets"}.
    """
    if beta_value < 1.0 and student is None:
        raise ValueError("a student is needed when beta < 1")
    slots = len(encoders)
    if env.num_envs % slots:
        raise ValueError(f"{env.num_envs} robots do not split into {slots} equal slots")
    per = env.num_envs // slots
    obs = env.get_observations()[obs_group]
    continued = windows is not None and windows.t > 0
    if windows is None:
        windows = SlidingWindows(env.num_envs, obs.shape[1], env.num_actions, horizon, stride, obs.device)
    done = [0] * slots
    pending: list[list[tuple[torch.Tensor, torch.Tensor]]] = [[] for _ in range(slots)]
    resets = 0
    t0 = time.monotonic()

    def flush(s: int) -> None:
        if pending[s]:
            sink(s, torch.cat([p[0] for p in pending[s]]), torch.cat([p[1] for p in pending[s]]))
            pending[s] = []

    def act(obs: torch.Tensor) -> torch.Tensor:
        """The applied action at ``obs``; first the windows that end here go to their slots' sinks."""
        nonlocal continued
        a_exp = expert(obs)
        if beta_value >= 1.0:
            applied = a_exp
        else:
            applied = beta_value * a_exp + (1.0 - beta_value) * student(obs)  # Algorithm 4, line 8
        if continued:  # this observation was pushed (and its windows taken) by the previous call
            continued = False
            env_ids = torch.zeros(0, dtype=torch.long)
            start_obs, acts = obs[:0], torch.zeros(0, horizon, env.num_actions)
        else:
            env_ids, start_obs, acts = windows.push(obs, a_exp)
        slot_of = torch.div(env_ids, per, rounding_mode="floor")
        for s in range(slots):
            if done[s] >= count:
                continue
            mine = torch.nonzero(slot_of == s).flatten()[:count - done[s]]
            if len(mine):
                pending[s].append((start_obs[mine].clone(), encoders[s](acts[mine])))
                done[s] += len(mine)
            if done[s] >= count or sum(len(p[0]) for p in pending[s]) >= flush_every:
                flush(s)
        if progress is not None:
            progress.update(min(done))
        return applied

    def restart(env_ids: torch.Tensor) -> None:
        nonlocal resets
        windows.reset(env_ids)
        resets += len(env_ids)

    steps = 0
    while min(done) < count:  # one episode length of steps per record call, until every slot has its count
        rec = record(env, policy=act, obs_group=obs_group, until=lambda: min(done) >= count, on_reset=restart,
                     no_grad=True, desc=f"collecting {count} datapoints per slot")
        steps += rec.steps
    for s in range(slots):
        flush(s)
    return {"datapoints": done, "env_steps": steps, "seconds": time.monotonic() - t0, "resets": resets}
