"""No host synchronisation inside ``LocomotionEnv.step`` (``core/sync_probe.py``), resets and pushes included.

On a GPU each host read of device memory (``.item()``, ``bool(t)``, ``torch.nonzero``, ...) waits for every
queued kernel, and each tensor built from Python numbers or numpy is a copy from the host. The probe counts
both by call site while ``env.step`` runs, on any device; the Warp backend on Warp's CPU device runs the
GPU code path (the controller and the leg dynamics in torch, on the backend's device) without a GPU.

Steps are counted after warm-up steps (constants are built and cached on first use; compiled functions compile),
without events and with resets (short episodes, a non-finite action), command resampling and pushes every few
steps. The env resets and pushes by masks (static shapes), so the only reads left are the Warp backend's, once
every ``check_every`` step calls (one PPO iteration).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from dls_quadruped.core.sync_probe import keep_installed, sync_probe
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv

SMALL = {"terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}
QUIET = {"commands": {"base_velocity": {"resampling_time_s": [100.0, 100.0]}}}


def _eventful(first_push_s: float) -> dict:
    """Episodes of 10 policy steps (0.02 s each), commands resampled every few steps, pushes every 0.02-0.08 s,
    a wrench drawn at every reset."""
    return {"env": {"episode_length_s": 0.2},
            "commands": {"base_velocity": {"resampling_time_s": [0.05, 0.1]}},
            "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [first_push_s, 0.08],
                                "params": {"velocity_range": [-0.5, 0.5]}},
                       "wrench": {"func": "external_wrench", "mode": "reset",
                                  "params": {"force_range": [-3.0, 3.0], "torque_range": [-0.3, 0.3]}}}}


EVENTFUL = _eventful(0.04)
EVENTFUL_AT_ONCE = _eventful(0.02)  # interval_s[0] <= step_dt: a robot reset this step may be pushed at once

WARP_BACKEND = {
    # sim/warp_backend.py checks device inputs on the device and reads the flags (and its contact overflow) once
    # every check_every (24) step calls: one PPO iteration
    "dls_quadruped/sim/warp_backend.py:_check_overflow",
    "dls_quadruped/sim/warp_inputs.py:raise_flagged",
}
"""The Warp backend's own reads: once per check_every step calls."""

CPU_BACKEND_FILES = ("dls_quadruped/sim/cpu_backend.py", "dls_quadruped/sim/cpu_workers.py",
                     "dls_quadruped/sim/shard.py")
"""The CPU backend moves state between torch and its MuJoCo/Pinocchio shards by design (it turns the env's masks
into row ids too): not counted."""


def _env(backend: str, overrides: dict, task: str = "base", compile: bool = False) -> LocomotionEnv:
    scene = {"backend": backend, "num_workers": 0, "compile": compile}
    return LocomotionEnv(load_task(task, overrides={**SMALL, **overrides, "scene": scene}), num_envs=4, seed=0,
                         verbose=False)


def _actions(steps: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    acts = [torch.randn(4, 28, generator=g) for _ in range(steps)]
    acts[3][2, 5] = float("nan")  # a non-finite action terminates robot 2 (and goes through check_actions)
    return acts


def _run(env: LocomotionEnv, steps: int, exclude: tuple[str, ...] = (), warmup: int = 1):
    """(probe report, number of robot resets, number of pushed robots, graphs dynamo compiled during the probed
    steps) of ``steps`` steps after ``warmup`` steps."""
    from torch._dynamo.utils import counters

    acts = _actions(steps + warmup)
    pushed = []
    if hasattr(env.scene.sim, "set_base_velocity"):
        push = env.scene.sim.set_base_velocity
        env.scene.sim.set_base_velocity = lambda mask, v: pushed.append(mask.clone()) or push(mask, v)
    for a in acts[:warmup]:
        env.step(a)
    dones = []
    graphs = counters["stats"]["unique_graphs"]
    with sync_probe(exclude=exclude) as report:
        for a in acts[warmup:]:
            dones.append(env.step(a)[2])
    graphs = counters["stats"]["unique_graphs"] - graphs
    return report, int(torch.stack(dones).sum()), int(torch.stack(pushed[warmup:]).sum()) if pushed else 0, graphs


def _check(report, steps: int, allowed: set[str], check_every: int = 24) -> None:
    assert report.outside(allowed) == {}, f"host reads or uploads inside env.step: {report.by_site()}"
    per_site: dict[str, int] = {}
    for site, n in report.counts.items():
        per_site[site.key()] = per_site.get(site.key(), 0) + n
    assert all(n <= 2 * (steps // check_every + 1) for n in per_site.values()), per_site  # flags and their names


@pytest.fixture(scope="module")
def warp():
    return pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")


@pytest.mark.parametrize("overrides", [QUIET, EVENTFUL, EVENTFUL_AT_ONCE],
                         ids=["no_events", "resets_pushes", "resets_pushes_at_once"])
def test_warp_step_reads_nothing_back(warp, overrides):
    env = _env("warp-cpu", overrides)
    try:
        steps = 12
        report, resets, pushes, _ = _run(env, steps)
    finally:
        env.close()
    assert resets > 0  # the non-finite action at least
    if overrides is not QUIET:
        assert resets > 4 and pushes > 2  # episodes of 10 steps, pushes every 1-4 steps
    _check(report, steps, WARP_BACKEND)


@pytest.mark.parametrize("overrides", [EVENTFUL, EVENTFUL_AT_ONCE], ids=["resets_pushes", "resets_pushes_at_once"])
def test_cpu_step_reads_nothing_back_outside_the_backend(overrides):
    """The same outside the CPU backend's files (cheap: no MuJoCo Warp needed, so CI runs it)."""
    env = _env("cpu", overrides)
    try:
        steps = 12
        report, resets, pushes, _ = _run(env, steps, exclude=CPU_BACKEND_FILES)
    finally:
        env.close()
    assert resets > 4 and pushes > 2
    _check(report, steps, set())


@pytest.mark.parametrize("task", ["rough", "speed"])
def test_curricula_decide_on_the_device(task):
    """Rough (terrain levels moved at every reset) and speed (the forward-speed range grown and the penalties switched
    on from the reset robots' episode rewards): the decisions and the logged values stay on the device, so a step
    with resets reads nothing back. The thresholds are lowered to 0 so the decisions do change things."""
    overrides = {"env": {"episode_length_s": 0.2}}
    if task == "speed":
        overrides["curriculum"] = {"speed": {"params": {"threshold": -1.0}},
                                   "penalties": {"params": {"threshold": -1.0}}}
    env = _env("cpu", overrides, task=task)
    try:
        steps = 12
        speed = env.command_manager.range("lin_vel_x") if task == "speed" else torch.zeros(2)
        upper_before = float(speed[1])
        report, resets, _, _ = _run(env, steps, exclude=CPU_BACKEND_FILES)
        logged = env.curriculum_manager.values
        log = env.episode_log.read()
        upper_after = float(speed[1])
        weights = env.reward_manager.weights.as_dict()
    finally:
        env.close()
    assert resets > 4
    assert all(isinstance(v, torch.Tensor) and v.dim() == 0 for v in logged.values())
    assert all(f"Curriculum/{k}" in log for k in logged)
    if task == "speed":  # every step with resets raised the range by 0.1 m/s; the penalties switched on
        assert upper_after > upper_before + 0.15 and weights["action_rate"] != 0.0
        assert log["Curriculum/penalties"] == 1.0
    _check(report, steps, set())


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["warp-cpu", "cpu"])
def test_compiled_step_reads_nothing_back_and_recompiles_nothing(backend):
    """``scene.compile: true``, resets and pushes at most steps: after the warm-up steps (compiles, first captures),
    no host read or upload in ``env.step`` (the Warp backend's once-per-iteration check aside), no compiled function
    fell back to eager, and in the steady state after that window none compiles again (static shapes: a reset of
    another number of robots is the same graph)."""
    if backend == "warp-cpu":
        pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    from dls_quadruped.core.compile import Fused
    from dls_quadruped.envs.mdp.events import _placement

    keep_installed()  # compiled below with the probe's wrappers in place (torch 2.11 guards on them)
    env = None
    try:
        env = _env(backend, EVENTFUL_AT_ONCE, compile=True)
        steps = 20
        report, resets, pushes, _ = _run(env, steps, exclude=CPU_BACKEND_FILES if backend == "cpu" else (), warmup=3)
        _, more_resets, _, graphs = _run(env, 10, warmup=0)  # first uses (a stream's first push) compiled above
        fused = [env.reward_manager._compute, env.observation_manager._groups, env.termination_manager._compute,
                 env.action_manager._convert, env.command_manager._compute, env.command_manager._integrate,
                 env._reset_bookkeeping, env.fused(_placement), env.schedule._draw]
        if backend == "warp-cpu":
            rate = env.scene.sim.rate
            fused += [rate._control, rate._settle, rate._terms, rate._publish, rate._store, rate._reset]
    finally:
        keep_installed(False)
        if env is not None:
            env.close()
    _check(report, steps, WARP_BACKEND if backend == "warp-cpu" else set())
    assert all(isinstance(f, Fused) and f.compiled for f in fused), [f.name for f in fused if not f.compiled]
    assert resets > 6 and pushes > 4 and more_resets > 2
    assert graphs == 0


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
        report, _, _, _ = _run(env, 3, exclude=CPU_BACKEND_FILES)
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


def test_kept_wrappers_count_only_inside_a_probe_and_spare_compiled_guards():
    """``keep_installed``: a function compiled after it guards on the wrappers, so calling it inside a probe does
    not compile it again (torch 2.11 guards on ``torch.tensor``'s identity; wrappers swapped in by the probe made
    every compiled function recompile inside it); the wrappers count only while a probe is active, and
    ``keep_installed(False)`` removes them."""
    compiles = []

    def counting(gm, example_inputs):
        compiles.append(1)
        return gm.forward

    @torch.compile(backend=counting, fullgraph=True, dynamic=False)
    def shifted(x):
        return x + torch.tensor([1.0, 2.0])

    plain = torch.tensor
    keep_installed()
    try:
        wrapped = torch.tensor
        assert wrapped is not plain
        shifted(torch.zeros(2))  # compiled here, outside any probe
        torch.as_tensor([3.0])  # no probe active: not counted anywhere
        with sync_probe(package=Path(__file__).parent) as report:
            out = shifted(torch.zeros(2))
            torch.as_tensor([3.0])  # eager: counted
        assert torch.tensor is wrapped  # kept after the probe
    finally:
        keep_installed(False)
    assert torch.tensor is plain and out.tolist() == [1.0, 2.0] and len(compiles) == 1
    assert [(s.function, s.kind, n) for s, n in report.counts.items()
            if s.function != "shifted"] == [("test_kept_wrappers_count_only_inside_a_probe_and_spare_compiled_guards",
                                              "upload", 1)]
