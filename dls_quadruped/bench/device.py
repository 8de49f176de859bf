"""Device benchmark: ``make bench DEVICE=cuda`` = ``python -m dls_quadruped.bench.device --device cuda``.

Three measurements on one simulator backend (``sim/interface.py``) and torch device, written to
``results/bench/device.json`` with the machine (GPU name, CPU model) and printed as markdown:

* **env**: ``LocomotionEnv.step`` steps/s (robot steps per wall second, random actions, resets and pushes included) for
  each task (base, rough) and number of robots (256 ... 16 384 on a GPU); a size that does not fit in memory
  is recorded as such and the next task goes on;
* **mpc**: the sampling MPC's solve for one robot at M samples (10 000 and 100 000), N = 10 (first-spline, forces
  only), the median of ``--solves`` solves after warm-up, with the cost kernel's share (``warp``, the GPU default,
  or the torch kernels ``fast``/``reference`` on the device; ``cpp`` only on the CPU); on CUDA each solve ends
  with a synchronisation, so the time is what the action's host read-out waits for (the ``warp`` kernel's share
  is the host's time for its graph launch: its cost against work is ``bench/mpc_warp.py``);
* **closed loop**: the naive-warm-start MPC driving B robots of the simple task on the same backend and device,
  simulated robot-seconds per wall second with the kernel's share.

On a machine without CUDA the same script runs with ``--device cpu --backend cpu`` (or ``warp-cpu``), which is
what the tests do at tiny sizes. Targets (one H100): base >= 300 000 and rough >= 150 000 env steps/s
at 4096 robots; MPC M = 10 000 <= 1 ms, M = 100 000 <= 3 ms.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, run_cli, torch_device
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model

GPU_SIZES = (256, 1024, 4096, 16384)
CPU_SIZES = (64, 256)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _out_of_memory(err: BaseException) -> bool:
    """torch's OOM, or Warp's failed allocation (a RuntimeError "Failed to allocate ... bytes on device")."""
    text = f"{type(err).__name__}: {err}".lower()
    return (isinstance(err, torch.cuda.OutOfMemoryError) or "out of memory" in text
            or ("failed to allocate" in text and "graph capture" not in text) or "cudaerrormemoryallocation" in text)


def machine(device: torch.device) -> dict:
    """What the numbers ran on."""
    out = {"cpu": cpu_model(), "device": str(device), "torch": torch.__version__}
    if device.type == "cuda":
        out["gpu"] = torch.cuda.get_device_name(device)
        out["gpu_memory_gib"] = round(torch.cuda.get_device_properties(device).total_memory / 2**30, 1)
    return out


BENCH_PUSH = {"func": "push_robot", "mode": "interval", "interval_s": [0.5, 1.0],
              "params": {"velocity_range": [-0.5, 0.5]}}
"""Pushes every 0.5-1 s per robot in the env rows (a task's own are 8-12 s apart, or none): a timed run of 60
steps (1.2 s) then includes pushes, and resets from the robots that random actions topple."""


def env_steps(task: str, num_envs: int, device: torch.device, backend: str, steps: int, warmup: int,
              capture: bool | None = None, compile: bool | None = None, cuda_graph: bool | None = None) -> dict:
    """Robot steps per second of ``task`` with ``num_envs`` robots (random actions, resets included);
    ``capture``: the Warp backends' graph replay on or off, ``compile``: ``scene.compile`` (None: the backend's
    default for either), ``cuda_graph``: ``scene.cuda_graph`` (the whole step replayed from one graph)."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    scene = {"backend": backend, "num_workers": 0 if backend != "cpu" else -1}
    if compile is not None:
        scene["compile"] = compile
    if cuda_graph is not None:
        scene["cuda_graph"] = cuda_graph
    cfg = load_task(task, overrides={"scene": scene, "events": {"push": BENCH_PUSH}})
    env = LocomotionEnv(cfg, num_envs=num_envs, device=str(device), seed=0, verbose=False)
    if capture is not None:
        env.scene.sim.capture = capture
    try:
        g = torch.Generator(device=device).manual_seed(0)
        for _ in range(warmup):
            env.step(torch.randn(num_envs, env.num_actions, generator=g, device=device))
        _sync(device)
        tic = time.perf_counter()
        resets = torch.zeros((), dtype=torch.int64, device=device)
        for _ in range(steps):
            _, _, dones, _ = env.step(torch.randn(num_envs, env.num_actions, generator=g, device=device))
            resets += dones.sum()  # read once, after the timing
        _sync(device)
        wall = time.perf_counter() - tic
        graphs = [getattr(env.scene.sim, k, None) for k in ("_step1", "_step2")]
        capture_errors = sorted({g.error for g in graphs if g is not None and g.error})
        step_graph = None if env.graph is None else {"captures": env.graph.captures, "replays": env.graph.replays,
                                                     "error": env.graph.error}
    finally:
        env.close()
    return {"task": task, "num_envs": num_envs, "steps": steps, "wall_s": wall, "steps_per_s": num_envs * steps / wall,
            "resets": int(resets), "capture": capture, "compile": compile,
            **({"capture_errors": capture_errors} if capture_errors else {}),
            **({"step_graph": step_graph} if step_graph else {})}


def mpc_solve(samples: int, horizon: int, device: torch.device, kernel: str, solves: int) -> dict:
    """Median solve and kernel time [s] for one robot (forces only, first-spline)."""
    from dls_quadruped.mpc import warm_start
    from dls_quadruped.mpc.config import SamplerConfig
    from dls_quadruped.mpc.cost import Refs
    from dls_quadruped.mpc.sampler import SamplingMPC
    from dls_quadruped.mpc.srbd import SRBDState

    cfg = SamplerConfig(num_samples=samples, horizon=horizon, kernel=kernel, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    mpc = SamplingMPC(cfg, device=device)
    feet = torch.tensor([[[0.24, 0.13, 0.02], [0.24, -0.13, 0.02], [-0.24, 0.13, 0.02], [-0.24, -0.13, 0.02]]],
                        device=device)
    z3 = torch.zeros(1, 3, device=device)
    state = SRBDState(torch.tensor([[0.0, 0.0, 0.32]], device=device), z3, z3.clone(), z3.clone(), feet)
    refs = Refs(torch.tensor([0.32], device=device), torch.tensor([[0.5, 0.0]], device=device),
                torch.zeros(1, device=device), feet.clone())
    ws = warm_start.nominal_trot(1, cfg).to(device)
    phase = torch.zeros(1, 4, device=device)
    total, kern = [], []
    for k in range(solves + 3):
        before = mpc.kernel_seconds
        _sync(device)
        tic = time.perf_counter()
        result = mpc.solve(state, refs, [ws], phase=phase)
        float(result.best_cost[0])  # the host read-out a controller waits for
        if k >= 3:
            total.append(time.perf_counter() - tic)
            kern.append(mpc.kernel_seconds - before)
    return {"samples": samples, "horizon": horizon, "kernel": kernel, "solve_s": statistics.median(total),
            "kernel_s": statistics.median(kern)}


def closed_loop(robots: int, seconds: float, samples: int, device: torch.device, backend: str, kernel: str) -> dict:
    """Naive-warm-start MPC on the simple task: simulated robot-seconds per wall second."""
    from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
    from dls_quadruped.closed_loop.episodes import commands, make_env
    from dls_quadruped.closed_loop.loop import run_closed_loop
    from dls_quadruped.mpc.config import SamplerConfig

    env = make_env(commands(robots, 0, None), seconds, seed=0, num_workers=0, device=str(device), backend=backend)
    try:
        ctrl = make_controller(ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=samples,
                                                                                         kernel=kernel)), env)
        traces = run_closed_loop(env, ctrl)
    finally:
        env.close()
    t = traces.timing
    return {"robots": robots, "seconds": seconds, "samples": samples, "kernel": kernel,
            "robot_seconds_per_second": t["robot_seconds_per_second"], "kernel_share": t["kernel_share"],
            "wall_s": t["wall"]}


def _table(rows: list[dict], cols: list[tuple[str, str, str]]) -> str:
    head = "| " + " | ".join(c[1] for c in cols) + " |\n|" + "---|" * len(cols) + "\n"
    body = ""
    for r in rows:
        cells = []
        for key, _, fmt in cols:
            v = r.get(key, "")
            cells.append(format(v, fmt) if isinstance(v, (int, float)) and fmt else str(v))
        body += "| " + " | ".join(cells) + " |\n"
    return head + body


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(prog="dls_quadruped.bench.device", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", type=torch_device, default="cuda" if torch.cuda.is_available() else "cpu",
                   help="torch device of the env and the MPC (default: cuda if available)")
    p.add_argument("--backend", default=None, help="simulator backend (default: cuda on a GPU, else cpu)")
    p.add_argument("--tasks", nargs="*", default=["base", "rough"], help="tasks of the env rows (none: skip them)")
    p.add_argument("--sizes", nargs="+", type=int, default=None,
                   help=f"robots per env (default {list(GPU_SIZES)} on a GPU, {list(CPU_SIZES)} on the CPU)")
    p.add_argument("--steps", type=int, default=60, help="measured env steps per size (60: 1.2 s, resets and pushes "
                                                         "included)")
    p.add_argument("--warmup", type=int, default=3, help="env steps before timing (Warp compiles on the first)")
    p.add_argument("--samples", nargs="*", type=int, default=[10000, 100000],
                   help="MPC samples M of the solve rows (none: skip them)")
    p.add_argument("--horizon", type=int, default=10)
    p.add_argument("--kernel", default=None, help="MPC kernel (default: warp on a GPU, cpp on the CPU)")
    p.add_argument("--solves", type=int, default=30)
    p.add_argument("--closed-loop-robots", nargs="*", type=int, default=None,
                   help="robots of the closed-loop rows (default 256 4096 on a GPU, 16 on the CPU; none: skip)")
    p.add_argument("--closed-loop-seconds", type=float, default=2.0)
    p.add_argument("--closed-loop-samples", type=int, default=10000)
    p.add_argument("--out", type=Path, default=Path("results/bench"))
    args = p.parse_args(argv)
    for name in ("steps", "solves", "horizon"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.warmup < 0:
        p.error(f"--warmup must be >= 0, got {args.warmup}")
    device = torch.device(args.device)
    gpu = device.type == "cuda"
    backend = args.backend or ("cuda" if gpu else "cpu")
    from dls_quadruped.sim.registry import check_backend

    try:
        check_backend(backend)
    except ValueError as err:
        p.error(str(err))
    kernel = args.kernel or ("warp" if gpu else "cpp")
    sizes = args.sizes or list(GPU_SIZES if gpu else CPU_SIZES)
    loop_robots = args.closed_loop_robots if args.closed_loop_robots is not None else ([256, 4096] if gpu else [16])
    result = {"machine": machine(device), "backend": backend, "kernel": kernel, "env": [], "mpc": [], "closed_loop": []}
    for task in args.tasks:
        for n in sizes:
            try:
                row = env_steps(task, n, device, backend, args.steps, args.warmup)
            except Exception as err:  # a size that does not fit is a result, not the end of the run
                if not _out_of_memory(err):
                    raise
                result["env"].append({"task": task, "num_envs": n, "error": "out of memory"})
                print(f"[bench.device] {task} N={n}: out of memory; larger sizes skipped", flush=True)
                break
            result["env"].append(row)
            print(f"[bench.device] {task} N={n}: {row['steps_per_s']:,.0f} steps/s", flush=True)
    for m in args.samples:
        row = mpc_solve(m, args.horizon, device, kernel, args.solves)
        result["mpc"].append(row)
        print(f"[bench.device] MPC M={m} N={args.horizon}: solve {1e3 * row['solve_s']:.2f} ms, "
              f"kernel {1e3 * row['kernel_s']:.2f} ms", flush=True)
    for b in loop_robots:
        row = closed_loop(b, args.closed_loop_seconds, args.closed_loop_samples, device, backend, kernel)
        result["closed_loop"].append(row)
        print(f"[bench.device] closed loop B={b}: {row['robot_seconds_per_second']:.2f} robot-s/s, "
              f"kernel share {row['kernel_share']:.0%}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out / "device.json")
    mach = result["machine"]
    print(f"\n{mach.get('gpu', mach['cpu'])} (device {device}, backend {backend}, MPC kernel {kernel})\n")
    print(_table(result["env"], [("task", "task", ""), ("num_envs", "N", "d"), ("steps_per_s", "steps/s", ",.0f"),
                                 ("error", "note", "")]))
    print(_table([{**r, "solve_ms": 1e3 * r["solve_s"], "kernel_ms": 1e3 * r["kernel_s"]} for r in result["mpc"]],
                 [("samples", "M", "d"), ("horizon", "N", "d"), ("solve_ms", "solve [ms]", ".3f"),
                  ("kernel_ms", "kernel [ms]", ".3f")]))
    if result["closed_loop"]:
        print(_table(result["closed_loop"], [("robots", "B", "d"), ("robot_seconds_per_second", "robot-s/s", ".2f"),
                                             ("kernel_share", "kernel share", ".2f")]))
    print(f"wrote {args.out / 'device.json'}")


if __name__ == "__main__":
    run_cli(main)
