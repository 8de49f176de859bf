"""What one ``LocomotionEnv.step`` costs a GPU, measured by call site: host syncs, kernel launches, busy time.

The probes of the GPU check (``bench/gpu_check.py``, sections ``syncs``, ``launches`` and ``gpu_busy``): each
builds the base task on a Warp backend, steps it a few times outside the count (compilation, graph capture),
then counts while it steps with random actions (robots fall and reset; pushes every ~0.3 s).
"""

from __future__ import annotations

import time
import traceback
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

import numpy as np
import torch


def sync_device(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA only: the CPU has none)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _site(frames: list[traceback.FrameSummary]) -> str:
    """The innermost frame of this package (else the innermost frame) as ``file:line``."""
    for f in reversed(frames):
        if "dls_quadruped" in f.filename and "gpu_probes" not in f.filename:
            return f"{f.filename.split('dls_quadruped/')[-1]}:{f.lineno}"
    return f"{frames[-1].filename}:{frames[-1].lineno}" if frames else "?"


def _base_with_pushes(backend: str) -> dict:
    return {"scene": {"backend": backend, "num_workers": 0},
            "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [0.2, 0.4],
                                "params": {"velocity_range": [-0.5, 0.5]}}}}


WARMUP_STEPS = 40
"""Env steps before any counted or timed window: a compiled step recompiles for the first few reset batch sizes
and captures its graphs on the first calls (docs/gpu.md), none of which belongs in a steady-state figure."""


def syncs(backend: str, device: torch.device, num_envs: int, steps: int, warmup: int = WARMUP_STEPS) -> dict:
    """Host synchronisations per ``env.step`` by site: torch's (CUDA sync debug mode) and Warp array reads."""
    import warp as wp

    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    env = LocomotionEnv(load_task("base", overrides=_base_with_pushes(backend)), num_envs=num_envs,
                        device=str(device), seed=0, verbose=False)
    from dls_quadruped.core.sync_probe import sync_probe

    sites: Counter = Counter()
    probe_sites: Counter = Counter()
    per_step, per_step_probe, done_steps = [], [], 0
    warp_reads = {"n": 0}
    orig_numpy = wp.array.numpy

    def counted_numpy(self, *a, **k):
        warp_reads["n"] += 1
        sites["warp.array.numpy @ " + _site(traceback.extract_stack()[:-1])] += 1
        return orig_numpy(self, *a, **k)

    try:
        g = torch.Generator(device=device).manual_seed(0)
        for _ in range(warmup):  # compile and capture outside the count
            env.step(torch.randn(num_envs, env.num_actions, generator=g, device=device))
        sync_device(device)
        wp.array.numpy = counted_numpy
        if device.type == "cuda":
            torch.cuda.set_sync_debug_mode("warn")
        for _ in range(steps):
            action = torch.randn(num_envs, env.num_actions, generator=g, device=device)
            with warnings.catch_warnings(record=True) as caught, sync_probe() as probe:
                warnings.simplefilter("always")
                before = warp_reads["n"]
                _, _, dones, _ = env.step(action)
            torch_syncs = [w for w in caught if "synchroniz" in str(w.message).lower()]
            for w in torch_syncs:
                sites[f"cuda @ {w.filename.split('dls_quadruped/')[-1]}:{w.lineno}"] += 1
            for site, k in probe.by_site().items():
                probe_sites[site] += k
            per_step.append(len(torch_syncs) + warp_reads["n"] - before)
            per_step_probe.append(probe.total)
            done_steps += int(bool(dones.any()))
    finally:
        if device.type == "cuda":
            torch.cuda.set_sync_debug_mode(0)
        wp.array.numpy = orig_numpy
        env.close()
    return {"num_envs": num_envs, "steps": steps, "warmup": warmup, "steps_with_resets": done_steps,
            "syncs_per_step_mean": float(np.mean(per_step)), "syncs_per_step_max": int(np.max(per_step)),
            "by_site": dict(sites.most_common(40)),
            "counted": "torch's CUDA sync debug mode + warp.array.numpy()" if device.type == "cuda"
            else "warp.array.numpy() only (torch's sync debug mode needs CUDA)",
            "probe_per_step_mean": float(np.mean(per_step_probe)), "probe_by_site": dict(probe_sites.most_common(40)),
            "probe": "core/sync_probe.py: Python-level host reads and uploads (the cuda count also sees C++ ones)"}


COMPILED_GRAPH = "## Call CompiledFxGraph"
"""The torch profiler's name prefix of a call of a ``torch.compile``'d graph; its direct children are its kernels."""


def count_torch_ops(events) -> tuple[int, int]:
    """(torch operators launched, of which inside compiled graphs) among a profiler's CPU ``events``.

    An operator counts once where the Python side dispatched it: a top-level ``aten::`` event (none of its
    ancestors an aten operator or a compiled graph; views and metadata ops included, so an upper bound on kernel
    launches), or a direct child of a compiled graph's call (its fused kernels, and its extern calls such as a
    LAPACK solve; CPU kernels are seen when ``torch._inductor.config.cpp.enable_kernel_profile`` was on when they
    were compiled).
    """
    total = fused = 0
    for e in events:
        parent = e.cpu_parent
        if parent is not None and parent.name.startswith(COMPILED_GRAPH):
            total, fused = total + 1, fused + 1
            continue
        if not e.name.startswith("aten::"):
            continue
        while parent is not None and not (parent.name.startswith("aten::") or parent.name.startswith(COMPILED_GRAPH)):
            parent = parent.cpu_parent
        total += parent is None
    return total, fused


def launches(backend: str, device: torch.device, num_envs: int, steps: int, compile: bool | None = None,
             warmup: int = 40) -> dict:
    """Warp kernel launches (graph replays count one each) and torch operators per ``env.step``, by kind.

    Counted: every ``wp.launch`` / ``wp.launch_tiled`` / ``wp.capture_launch`` call (MuJoCo Warp's kernels outside a
    captured graph, and each graph) and every torch operator the step launches (:func:`count_torch_ops`, from the
    torch profiler: eager operators, and the kernels of the physics step's compiled graphs, ``sim/warp_control.py``).
    ``compile``: the scene's ``compile`` (None: the backend's default, on for CUDA). ``warmup`` steps before the count
    (compiling and capturing, including the reset path's compiles for one robot and for several, happen there).
    """
    import torch._inductor.config as inductor_config
    import warp as wp
    from torch.profiler import ProfilerActivity, profile

    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    counts = {"warp": 0}
    names = ("launch", "launch_tiled", "capture_launch")
    originals = {k: getattr(wp, k) for k in names}

    def counted(fn):
        def wrapper(*a, **k):
            counts["warp"] += 1
            return fn(*a, **k)
        return wrapper

    overrides = _base_with_pushes(backend)
    overrides["scene"]["compile"] = compile
    kernel_profile = inductor_config.cpp.enable_kernel_profile
    inductor_config.cpp.enable_kernel_profile = True  # CPU kernels of compiled graphs show in the profiler
    try:
        env = LocomotionEnv(load_task("base", overrides=overrides), num_envs=num_envs, device=str(device), seed=0,
                            verbose=False)
    finally:
        inductor_config.cpp.enable_kernel_profile = kernel_profile
    rows = []
    try:
        g = torch.Generator(device=device).manual_seed(0)
        for _ in range(warmup):
            env.step(torch.randn(num_envs, env.num_actions, generator=g, device=device))
        import mujoco_warp._src.warp_util  # noqa: F401  (MuJoCo Warp calls wp.launch through the warp module)
        for k in names:
            setattr(wp, k, counted(originals[k]))
        for _ in range(steps):
            action = torch.randn(num_envs, env.num_actions, generator=g, device=device)
            counts["warp"] = 0
            with profile(activities=[ProfilerActivity.CPU]) as prof:
                _, _, dones, _ = env.step(action)
            ops, fused = count_torch_ops(prof.events())
            rows.append((counts["warp"], ops, fused, bool(dones.any())))
        compiled = env.scene.sim.rate.compiled
    finally:
        for k in names:
            setattr(wp, k, originals[k])
        env.close()
    plain = [r for r in rows if not r[3]] or rows
    reset = [r for r in rows if r[3]]
    return {"num_envs": num_envs, "steps": steps, "compiled": compiled,
            "warp_launches_per_step": float(np.mean([r[0] for r in plain])),
            "torch_ops_per_step": float(np.mean([r[1] for r in plain])),
            "torch_ops_in_compiled_graphs_per_step": float(np.mean([r[2] for r in plain])),
            "warp_launches_reset_step": float(np.mean([r[0] for r in reset])) if reset else None,
            "torch_ops_reset_step": float(np.mean([r[1] for r in reset])) if reset else None,
            "steps_with_resets": len(reset)}


def gpu_busy(backend: str, device: torch.device, num_envs: int, steps: int, warmup: int = WARMUP_STEPS,
             cuda_graph: bool = False) -> dict:
    """GPU kernel time over wall time per env step, each from its own window after ``warmup`` steps: wall time
    without the profiler (which slows the host several-fold), kernel time from the profiler (CUPTI sees Warp's
    kernels too) over the same number of steps. ``cuda_graph``: the step replayed from one graph."""
    from torch.profiler import ProfilerActivity, profile

    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    if device.type != "cuda":
        return {"skipped": "needs CUDA"}
    scene = {"backend": backend, "num_workers": 0, "cuda_graph": cuda_graph}
    env = LocomotionEnv(load_task("base", overrides={"scene": scene}), num_envs=num_envs, device=str(device), seed=0,
                        verbose=False)
    try:
        g = torch.Generator(device=device).manual_seed(0)
        actions = lambda: torch.randn(num_envs, env.num_actions, generator=g, device=device)
        for _ in range(warmup):
            env.step(actions())
        sync_device(device)
        tic = time.perf_counter()
        for _ in range(steps):
            env.step(actions())
        sync_device(device)
        wall = time.perf_counter() - tic
        with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            for _ in range(steps):
                env.step(actions())
            sync_device(device)
        kernels = [e for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA]
        kernel_s = sum(e.device_time for e in kernels) * 1e-6
    finally:
        env.close()
    graph = None if env.graph is None else {"captures": env.graph.captures, "error": env.graph.error}
    return {"num_envs": num_envs, "cuda_graph": cuda_graph, "step_graph": graph, "steps": steps, "warmup": warmup,
            "wall_s_per_step": wall / steps,
            "kernel_s_per_step": kernel_s / steps, "busy_fraction": kernel_s / wall,
            "kernels_per_step": len(kernels) / steps,
            "note": "wall time from an unprofiled window, kernel time from a profiled one of as many steps"}


FAULTY = {"nan_action": 1, "posinf_action": 2, "neginf_action": 3, "diverged_push": 4}
"""The fault trials' robots: a NaN, a +inf and a -inf action row at one step, and a push at 5 km/s (beyond the
backends' velocity bound) into the same step."""
WARP_FAULTY = {"contact_overflow": 5}
"""On the Warp backends also: a robot put with its base 5 cm below the ground, every link in it (measured on
warp-cpu: 24 contacts and 96 constraint rows, over base's ``njmax`` of 64), whose world overflows MuJoCo Warp's
constraint rows."""


def _sink(env, row: int) -> None:
    """Reset robot ``row`` where it is, its base 5 cm below the (flat) ground: every link penetrates it."""
    s = env.state
    mask = torch.zeros(env.num_envs, dtype=torch.bool, device=s.base_pos_w.device)
    mask[row] = True
    pos = s.base_pos_w.double().clone()
    pos[:, 2] = -0.05
    env.scene.sim.reset(mask, pos, s.base_quat_w.double(), s.joint_pos.double())


def faults(backend: str, device: torch.device, num_envs: int = 8, steps: int = 8, fault_step: int = 4) -> dict:
    """Fault trials: the robots of ``FAULTY`` (and on the Warp backends ``WARP_FAULTY``) get their fault at policy
    step ``fault_step``; each must be reset (done) at that step or the next, every observation must stay finite, and
    the other robots must run as in the same env without faults (max |difference| of their observations; 0 on the
    CPU backend, where worlds do not interact). ``overflowed``: the robots whose world MuJoCo Warp flagged out of
    contacts or constraint rows during the fault step; ``sim_diverged``: the robots the ``sim_diverged``
    termination ended (those of the push and the overflow); ``sim_diverged_logged``: how many the episode log
    counted (its mean over the steps with resets: the faults' step is the only one)."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    faulty = dict(FAULTY, **(WARP_FAULTY if backend != "cpu" else {}))
    if num_envs <= max(faulty.values()):
        raise ValueError(f"faults: num_envs must be > {max(faulty.values())}, got {num_envs}")
    overrides = {"env": {"episode_length_s": 100.0}, "events": {},
                 "commands": {"base_velocity": {"resampling_time_s": [100.0, 100.0]}},
                 "scene": {"backend": backend, "num_workers": 0}}
    g = torch.Generator().manual_seed(0)
    actions = [0.3 * torch.randn(num_envs, 28, generator=g) for _ in range(steps)]
    runs = []
    for with_faults in (False, True):
        env = LocomotionEnv(load_task("base", overrides=overrides), num_envs=num_envs, device=str(device), seed=0,
                            verbose=False)
        overflow: list[torch.Tensor] = []
        try:
            obs, dones, diverged = [], [], []
            for k, a in enumerate(actions):
                a, sunk = a.to(device), False
                if with_faults and k == fault_step:
                    a = a.clone()
                    for row, v in zip((1, 2, 3), (float("nan"), float("inf"), float("-inf"))):
                        a[row] = v
                    ids = torch.tensor([FAULTY["diverged_push"]], device=device)
                    env.scene.sim.set_base_velocity(ids, torch.tensor([[0.0, 0.0, 5.0e3]], device=device))
                    if "contact_overflow" in faulty:
                        _sink(env, faulty["contact_overflow"])
                        sunk = True
                with _overflow_seen(env.scene.sim) if sunk else nullcontext([]) as seen:
                    o, _, d, _ = env.step(a)
                overflow += seen
                obs.append(o["policy"].cpu())
                dones.append(d.bool().cpu())
                diverged.append(env.termination_manager.term_dones["sim_diverged"].cpu().clone())
            counted = env.episode_log.read().get("Episode_Termination/sim_diverged", 0.0)
        finally:
            env.close()
        runs.append((torch.stack(obs), torch.stack(dones), torch.stack(diverged), overflow, counted))
    (ref_obs, *_), (obs, dones, diverged, overflow, counted) = runs
    others = [i for i in range(num_envs) if i not in faulty.values()]
    reset = {name: bool(dones[fault_step:fault_step + 2, i].any()) for name, i in faulty.items()}
    return {"num_envs": num_envs, "fault_step": fault_step, "reset": reset, "all_reset": all(reset.values()),
            "others_reset": int(dones[:, others].sum()), "finite": bool(torch.isfinite(obs).all()),
            "others_max_abs_diff": float((obs[:, others] - ref_obs[:, others]).abs().max()),
            "overflowed": [int(i) for i in torch.nonzero(torch.stack(overflow).any(0)).flatten()] if overflow else [],
            "sim_diverged": [int(i) for i in torch.nonzero(diverged.any(0)).flatten()],
            "sim_diverged_logged": counted}


@contextmanager
def _overflow_seen(sim) -> Iterator[list[torch.Tensor]]:
    """While the block runs, MuJoCo Warp's contact and constraint-row overflow bits of every world, (N,) bool, before
    each physics step's ``settle`` (which flags those robots diverged) of ``sim`` (a Warp backend)."""
    from dls_quadruped.sim.warp_collision import ALLOCATION_OVERFLOWS

    seen: list[torch.Tensor] = []
    settle = sim.rate.settle

    def recording() -> None:
        seen.append(((sim._overflow & ALLOCATION_OVERFLOWS) != 0).cpu())
        settle()

    sim.rate.settle = recording
    try:
        yield seen
    finally:
        sim.rate.settle = settle


def graph_agreement(backend: str, device: torch.device, num_envs: int, steps: int, warmup: int = 3) -> dict:
    """The env step replayed from one captured graph (``scene.cuda_graph``, ``envs/env_graph.py``) against the eager
    step: three envs of the same seed and actions (random, robots fall and reset, pushes every ~0.3 s), two eager and
    one graphed. Per step the largest base-position difference and the number of differing episode ends, graphed
    against eager beside eager against eager: on CUDA contact order comes from atomics, so two eager runs differ
    too and the graph is judged against that; on ``warp-cpu`` (an emulated graph) both are 0."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    def make(graph: bool) -> LocomotionEnv:
        overrides = _base_with_pushes(backend)
        overrides["scene"]["cuda_graph"] = graph
        return LocomotionEnv(load_task("base", overrides=overrides), num_envs=num_envs, device=str(device), seed=0,
                             verbose=False)

    envs = [make(False), make(False), make(True)]
    envs[2].graph.warmup = warmup
    try:
        g = torch.Generator(device=device).manual_seed(0)
        pos, dones = [], []
        for _ in range(steps):
            act = torch.randn(num_envs, envs[0].num_actions, generator=g, device=device)
            outs = [env.step(act) for env in envs]
            p = [env.state.base_pos_w for env in envs]
            pos.append(torch.stack([(p[1] - p[0]).abs().amax(), (p[2] - p[0]).abs().amax()]))
            dones.append(torch.stack([(outs[1][2] != outs[0][2]).sum(), (outs[2][2] != outs[0][2]).sum()]))
        pos_t, dones_t = torch.stack(pos).tolist(), torch.stack(dones).tolist()  # read once, at the end
        graph = envs[2].graph
        first = warmup  # the captured step's index
        return {"num_envs": num_envs, "steps": steps, "warmup": warmup, "captures": graph.captures,
                "replays": graph.replays, "error": graph.error,
                "max_base_pos_diff_m": {"eager_vs_eager": max(r[0] for r in pos_t),
                                        "graph_vs_eager": max(r[1] for r in pos_t),
                                        "graph_vs_eager_first_10_replays": max(r[1] for r in pos_t[first:first + 10])},
                "differing_dones": {"eager_vs_eager": sum(r[0] for r in dones_t),
                                    "graph_vs_eager": sum(r[1] for r in dones_t)},
                "per_step_base_pos_diff_m": [[round(a, 9), round(b, 9)] for a, b in pos_t]}
    finally:
        for env in envs:
            env.close()
