"""No host synchronisation inside ``LocomotionEnv.step`` beyond a written allow-list (``core/sync_probe.py``).

On a GPU each host read of device memory (``.item()``, ``bool(t)``, ``torch.nonzero``, ...) waits for every
queued kernel, and each tensor built from Python numbers or numpy is a copy from the host. The probe counts
both by call site while ``env.step`` runs, on any device; the Warp backend on Warp's CPU device runs the
GPU code path (the controller and the leg dynamics in torch, on the backend's device) without a GPU.

Steps are counted after one warm-up step (constants are built and cached on first use), without events and
with resets (short episodes, a non-finite action), command resampling and pushes every few steps.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from dls_quadruped.core.sync_probe import sync_probe
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv

SMALL = {"terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}
QUIET = {"commands": {"base_velocity": {"resampling_time_s": [100.0, 100.0]}}}


def _eventful(first_push_s: float) -> dict:
    """Episodes of 10 policy steps (0.02 s each), commands resampled every few steps, pushes every 0.02-0.08 s."""
    return {"env": {"episode_length_s": 0.2},
            "commands": {"base_velocity": {"resampling_time_s": [0.05, 0.1]}},
            "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [first_push_s, 0.08],
                                "params": {"velocity_range": [-0.5, 0.5]}}}}


EVENTFUL = _eventful(0.04)  # interval_s[0] > step_dt: the pushes' robots are read with the resets
EVENTFUL_AT_ONCE = _eventful(0.02)  # interval_s[0] <= step_dt: a robot reset this step may be pushed at once

PER_STEP = {
    # the backends reset and push robots by row id (SimBackend.reset), so the env reads how many robots reset and
    # how many each interval term pushes, in one read (the ids then come from torch.nonzero_static)
    "dls_quadruped/envs/env.py:_finish_step": 1,
    # an interval term with interval_s[0] <= step_dt finds its robots after the resets: one read per such term
    "dls_quadruped/envs/managers/event.py:apply": 1,
}
"""Sites allowed in every step, with how many reads each may make per step (per such interval term for events)."""

ON_RESET = {
    # a curriculum that switches reward weights on (penalties_when_walking) decides on the host
    "dls_quadruped/envs/managers/reward.py:episode_fraction",
}
"""Sites allowed on steps with resets only."""

WARP_BACKEND = {
    # sim/warp_backend.py checks device inputs on the device and reads the flags (and its contact overflow) once
    # every check_every (24) step calls: at most once in these runs
    "dls_quadruped/sim/warp_backend.py:_check_overflow",
    "dls_quadruped/sim/warp_backend.py:check_inputs",
}
"""The Warp backend's own reads: once per check_every step calls."""

CPU_BACKEND_FILES = ("dls_quadruped/sim/cpu_backend.py", "dls_quadruped/sim/cpu_workers.py",
                     "dls_quadruped/sim/shard.py")
"""The CPU backend moves state between torch and its MuJoCo/Pinocchio shards by design: not counted."""


def _env(backend: str, overrides: dict) -> LocomotionEnv:
    scene = {"backend": backend, "num_workers": 0}
    return LocomotionEnv(load_task("base", overrides={**SMALL, **overrides, "scene": scene}), num_envs=4, seed=0,
                         verbose=False)


def _actions(steps: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    acts = [torch.randn(4, 28, generator=g) for _ in range(steps)]
    acts[3][2, 5] = float("nan")  # a non-finite action terminates robot 2 (and goes through check_actions)
    return acts


def _run(env: LocomotionEnv, steps: int, exclude: tuple[str, ...] = ()):
    """(probe report, number of robot resets) of ``steps`` steps after one warm-up step."""
    acts = _actions(steps + 1)
    env.step(acts[0])
    dones = []
    with sync_probe(exclude=exclude) as report:
        for a in acts[1:]:
            dones.append(env.step(a)[2])
    return report, int(torch.stack(dones).sum())


def _check(report, steps: int, allowed: set[str], interval_terms: int) -> None:
    assert report.outside(allowed) == {}, f"host reads or uploads inside env.step: {report.by_site()}"
    per_site: dict[str, int] = {}
    for site, n in report.counts.items():
        per_site[site.key()] = per_site.get(site.key(), 0) + n
    assert per_site.get("dls_quadruped/envs/env.py:_finish_step", 0) <= steps, per_site
    assert per_site.get("dls_quadruped/envs/managers/event.py:apply", 0) <= steps * interval_terms, per_site


@pytest.fixture(scope="module")
def warp():
    return pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")


@pytest.mark.parametrize("overrides,interval_terms", [(QUIET, 0), (EVENTFUL, 0), (EVENTFUL_AT_ONCE, 1)],
                         ids=["no_events", "resets_pushes", "resets_pushes_at_once"])
def test_warp_step_reads_the_host_only_at_allowed_sites(warp, overrides, interval_terms):
    env = _env("warp-cpu", overrides)
    try:
        steps = 12
        report, resets = _run(env, steps)
        checks = sum(n for s, n in report.counts.items() if s.key() == "dls_quadruped/envs/managers/event.py:apply")
    finally:
        env.close()
    assert resets > 0  # the non-finite action at least
    if overrides is not QUIET:
        assert resets > 4  # episodes of 10 steps
    assert (checks > 0) == bool(interval_terms)  # the push term read its own robots only when it had to
    _check(report, steps, set(PER_STEP) | ON_RESET | WARP_BACKEND, interval_terms)


@pytest.mark.parametrize("overrides,interval_terms", [(EVENTFUL, 0), (EVENTFUL_AT_ONCE, 1)],
                         ids=["resets_pushes", "resets_pushes_at_once"])
def test_cpu_step_reads_the_host_only_at_allowed_sites(overrides, interval_terms):
    """The same outside the CPU backend's files (cheap: no MuJoCo Warp needed, so CI runs it)."""
    env = _env("cpu", overrides)
    try:
        steps = 12
        report, resets = _run(env, steps, exclude=CPU_BACKEND_FILES)
    finally:
        env.close()
    assert resets > 4
    _check(report, steps, set(PER_STEP) | ON_RESET, interval_terms)


def test_the_terrain_curriculum_reads_nothing_back_during_the_step():
    """Rough (terrain levels moved at every reset): the curriculum's logged mean level stays on the device, so a step
    with resets reads the host only where base's does."""
    env = LocomotionEnv(load_task("rough", overrides={**SMALL, "env": {"episode_length_s": 0.2},
                                                      "scene": {"backend": "cpu", "num_workers": 0}}),
                        num_envs=4, seed=0, verbose=False)
    try:
        steps = 12
        report, resets = _run(env, steps, exclude=CPU_BACKEND_FILES)
        logged = env.curriculum_manager.values["terrain_levels"]
    finally:
        env.close()
    assert resets > 4
    assert isinstance(logged, torch.Tensor) and logged.dim() == 0
    _check(report, steps, set(PER_STEP) | ON_RESET, 0)


def test_pushes_read_with_the_resets_are_the_pushes_found_after_them(monkeypatch):
    """The robots a push term fires on, read before the resets (``EventManager.due``), are the ones ``apply``
    finds itself after them: two envs, one with ``due`` disabled, push the same robots at the same steps and give
    bit-identical steps with resets."""
    from dls_quadruped.envs.managers.event import EventManager

    def rollout(env: LocomotionEnv) -> tuple[list[torch.Tensor], list[tuple[int, list[int]]]]:
        out, pushed, step = [], [], [0]
        push = env.scene.sim.set_base_velocity
        env.scene.sim.set_base_velocity = lambda ids, v: pushed.append((step[0], ids.tolist())) or push(ids, v)
        try:
            for step[0], a in enumerate(_actions(16)):
                obs, rew, dones, _ = env.step(a)
                out += [obs["policy"], rew, dones, env.state.base_lin_vel_w]
        finally:
            env.close()
        return out, pushed

    calls: list[int] = []
    due = EventManager.due
    monkeypatch.setattr(EventManager, "due", lambda self, dt, r: calls.append(1) or due(self, dt, r))
    read_with_resets, pushed = rollout(_env("cpu", EVENTFUL))
    monkeypatch.setattr(EventManager, "due", lambda self, dt, r: {})
    found_after, pushed_after = rollout(_env("cpu", EVENTFUL))
    assert len(calls) == 16 and len(pushed) > 4  # pushes every 2-4 steps
    assert pushed == pushed_after
    for a, b in zip(read_with_resets, found_after, strict=True):
        assert torch.equal(a, b)


def test_probe_catches_planted_reads_and_uploads():
    """A reward term that reads its value back and uploads a constant is caught, at the reward manager's call
    site (the innermost frame inside the package), once per step each; nothing is counted after the probe."""
    env = _env("cpu", QUIET)
    term = env.reward_manager.terms[0]
    original = term.func

    def leaky(env_, **params):
        value = original(env_, **params)
        value.sum().item()  # planted host read
        bool(value.any())  # planted host read
        torch.as_tensor([1.0, 2.0])  # planted upload of a Python list
        return value

    term.func = leaky
    try:
        report, _ = _run(env, 3, exclude=CPU_BACKEND_FILES)
        after = env.step(torch.zeros(4, 28))
        with sync_probe(exclude=CPU_BACKEND_FILES) as empty:
            pass
    finally:
        env.close()
    assert after is not None and empty.total == 0
    leaks = {(s.key(), s.kind): n for s, n in report.counts.items()
             if s.key() == "dls_quadruped/envs/managers/base.py:__call__"}
    assert leaks == {("dls_quadruped/envs/managers/base.py:__call__", "item"): 3,
                     ("dls_quadruped/envs/managers/base.py:__call__", "__bool__"): 3,
                     ("dls_quadruped/envs/managers/base.py:__call__", "upload"): 3}
    assert "item" not in torch.Tensor.__dict__ and torch.Tensor.item is torch._C.TensorBase.item  # unwrapped


def test_probe_lets_torch_compile_trace_through_it():
    """A function compiled while the probe is active (a recompile inside ``env.step`` on a GPU: a new reset batch
    size) traces through the wrapped entry points instead of failing on the probe's frame walk (it did on the
    H100, 2026-11-27). What the compiled graph does at run time is still counted: with the ``eager`` backend its
    generated code calls ``torch.tensor`` (the wrapper) on every call, a real upload."""
    @torch.compile(backend="eager", fullgraph=True, dynamic=False)
    def shifted(x):
        return x + torch.tensor([1.0, 2.0])  # an upload of a Python list, traced into the graph

    plain = torch.tensor
    with sync_probe(package=Path(__file__).parent) as report:  # this folder: the test's own calls count
        assert torch.tensor is not plain  # wrapped while the probe is active
        out = shifted(torch.zeros(2))
        torch.as_tensor([3.0])  # eager, outside the compiled function: counted
    assert out.tolist() == [1.0, 2.0]
    assert sorted((s.function, s.kind, n) for s, n in report.counts.items()) == [
        ("shifted", "upload", 1), ("test_probe_lets_torch_compile_trace_through_it", "upload", 1)]
