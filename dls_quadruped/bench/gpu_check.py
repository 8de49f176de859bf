"""The ten-minute GPU check: ``make gpu-check`` (= ``python -m dls_quadruped.bench.gpu_check``).

One script for a first session on a GPU machine. It writes ``<out>/report.json`` after every section, so a run
cut short still leaves what it measured, and gives each section a share of ``--budget-s``:

1. ``versions`` -- GPU, driver, CUDA, Warp, MuJoCo Warp, MuJoCo, torch, Python, CPU;
2. ``compile`` -- seconds to build the first backend and run its first steps (Warp compiles MuJoCo Warp's
   kernels on a fresh machine), flat scene;
3. ``graph`` -- the env step replayed from one captured graph (``scene.cuda_graph``, ``envs/env_graph.py``):
   its agreement with the eager step beside two eager runs' (``gpu_probes.graph_agreement``), then env steps/s at
   4 096 robots with and without it and at 16 384 with it;
4. ``trajectories`` -- the committed ``cpu``-backend reference runs (``bench/reference_runs.py``: standing, a trot,
   a push with mass/friction/force changes, robots on rough tiles) replayed on the backend, max deviations;
5. ``syncs`` -- host synchronisations inside ``LocomotionEnv.step`` by call site (torch's CUDA sync debug mode,
   plus Warp array reads), random actions so robots fall and reset, pushes every ~0.3 s;
6. ``launches`` -- Warp launches and torch operators per env step, compiled and eager (4 robots);
7. ``faults`` -- NaN/inf actions, a 5 km/s push and a sunk robot: each reset and counted, the others unaffected;
8. ``env`` -- env steps/s (robot steps per wall second) for base: 4 096 robots with the torch work compiled
   (``scene.compile``, the CUDA default) and eager side by side, 16 384 and 65 536 compiled, 4 096 launched kernel
   by kernel instead of replayed from captured graphs;
9. ``gpu_busy`` -- the fraction of a few env steps' wall time in which the GPU ran kernels (torch profiler);
10. ``mpc`` -- the sampling MPC's solve at M = 10 000 and 100 000 (``bench/device.py``);
11. ``rough`` -- the rough scene: first build (the terrain-culling collision kernels compile here) and env
   steps/s at 4 096 robots; after the base rows because a fresh machine spends minutes compiling it;
12. ``train`` -- PPO on base at ``--train-envs`` robots for the time left; the policy, checkpoint and learning
   curve are copied into ``<out>``.

Without CUDA the same script runs on ``warp-cpu`` at small sizes (what the tests do).
The probes behind ``syncs``, ``launches`` and ``gpu_busy`` are ``bench/gpu_probes.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.bench.device import env_steps, machine, mpc_solve
from dls_quadruped.bench.gpu_probes import (
    WARMUP_STEPS,
    faults,
    gpu_busy,
    graph_agreement,
    launches,
    sync_device,
    syncs,
)
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.json_io import write_json

SECTIONS = ("versions", "compile", "graph", "trajectories", "syncs", "launches", "faults", "env", "gpu_busy", "mpc",
            "rough", "train")


class Report:
    """The JSON report, rewritten (atomically) whenever a section ends."""

    def __init__(self, path: Path, budget_s: float):
        self.path, self.budget_s, self.t0 = path, budget_s, time.monotonic()
        self.data: dict = {"budget_s": budget_s, "sections": {}}

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def left(self) -> float:
        return self.budget_s - self.elapsed()

    def put(self, section: str, value: dict) -> None:
        self.data["sections"][section] = value
        self.data["elapsed_s"] = round(self.elapsed(), 1)
        write_json(self.data, self.path)
        print(f"[gpu_check] {section} ({self.elapsed():.0f} s): {json.dumps(value, default=str)[:600]}", flush=True)


def versions(device: torch.device) -> dict:
    import mujoco
    import warp as wp

    out = {**machine(device), "python": platform.python_version(), "mujoco": mujoco.__version__,
           "warp": wp.config.version}
    try:
        from importlib.metadata import version

        out["mujoco_warp"] = version("mujoco-warp")
    except Exception as err:  # noqa: BLE001 - a source checkout without metadata
        out["mujoco_warp"] = f"unknown ({err})"
    wp.init()
    if device.type == "cuda":
        out["cuda_torch"] = torch.version.cuda
        out["warp_cuda_driver"] = ".".join(map(str, wp.get_cuda_driver_version() or ()))
        out["conditional_graphs"] = bool(wp.is_conditional_graph_supported())
        try:
            smi = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total",
                                  "--format=csv,noheader"],
                                 capture_output=True, text=True, timeout=20, check=False)
            out["nvidia_smi"] = smi.stdout.strip()
        except (OSError, subprocess.TimeoutExpired) as err:
            out["nvidia_smi"] = f"unavailable ({err})"
    return out


def compile_times(backend: str, device: torch.device, scenes: tuple[str, ...] = ("flat", "rough")) -> dict:
    """First backend build and first steps of each of ``scenes`` (kernels compile here on a fresh machine)."""
    import mujoco

    from dls_quadruped.bench.reference_runs import ROUGH_TERRAIN
    from dls_quadruped.robots.aliengo import constants as C
    from dls_quadruped.sim.interface import SimConfig
    from dls_quadruped.sim.registry import make_backend
    from dls_quadruped.sim.terrain import build_scene

    models = {"flat": lambda: mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)),
              "rough": lambda: build_scene(ROUGH_TERRAIN)[0]}
    out = {}
    for name in scenes:
        model = models[name]()
        tic = time.perf_counter()
        with make_backend(backend, model, 4, SimConfig(num_workers=0, nthread=1)) as sim:
            built = time.perf_counter() - tic
            for _ in range(3):  # uncaptured first step, capture, replay
                sim.step(2)
            sync_device(device)
            first = time.perf_counter() - tic - built
            tic2 = time.perf_counter()
            sim.step(2)
            sync_device(device)
            out[name] = {"build_s": built, "first_steps_s": first, "warm_step_s": time.perf_counter() - tic2}
    return out


def trajectories(backend: str) -> dict:
    from dls_quadruped.bench.reference_runs import REFERENCE_PATH, SCENARIOS, compare
    from dls_quadruped.sim.interface import SimConfig

    refs = np.load(REFERENCE_PATH)
    out = {}
    for name, run in SCENARIOS.items():
        tic = time.perf_counter()
        try:
            traj = run(backend, SimConfig(num_workers=0, nthread=1))
            out[name] = {f"vs_{ref}": compare(name, traj, refs[f"{ref}/{name}"]) for ref in ("cpu", "warp-cpu")}
            out[name]["wall_s"] = time.perf_counter() - tic
        except Exception as err:  # noqa: BLE001 - a scenario that fails is a finding; the others still run
            out[name] = {"ok": False, "error": f"{type(err).__name__}: {err}"}
    return out


def env_throughput(backend: str, device: torch.device, rows: list[tuple], steps: int,
                   report: Report, reserve_s: float, section: str = "env", warmup: int = 3) -> list[dict]:
    """Env steps/s per (task, N, captured, compiled[, cuda_graph]) row, in the order given (the most telling first);
    stops early when the budget runs low. ``compiled`` None: ``scene.compile``'s default (on for CUDA);
    ``cuda_graph``: the whole step replayed from one graph (``scene.cuda_graph``, default off)."""
    from dls_quadruped.bench.device import _out_of_memory

    out = []
    for task, n, captured, compiled, *graph in rows:
        cuda_graph = graph[0] if graph else None
        key = {"task": task, "num_envs": n, "captured": captured, "compiled": compiled, "cuda_graph": cuda_graph}
        if report.left() < reserve_s:
            out.append({**key, "skipped": "budget"})
            continue
        try:
            row = env_steps(task, n, device, backend, steps, warmup=warmup, capture=captured, compile=compiled,
                            cuda_graph=cuda_graph)
            out.append({**row, **key})
        except Exception as err:  # noqa: BLE001 - recorded in the row; the next size still runs
            out.append({**key, "error": "out of memory" if _out_of_memory(err)
                        else f"{type(err).__name__}: {str(err)[:300]}"})
        if device.type == "cuda":
            torch.cuda.empty_cache()
        report.put(section, {"rows": out})
    return out


def mpc_rows(device: torch.device, sizes: tuple[int, ...], solves: int, report: Report) -> dict:
    """The MPC's solve per M, the report rewritten after each (the first CUDA compile of a size can take minutes,
    docs/gpu.md)."""
    rows = []
    for m in sizes:
        print(f"[gpu_check] mpc: M = {m} (compiles on first use) at {report.elapsed():.0f} s", flush=True)
        rows.append(mpc_solve(m, 10, device, "fast", solves))
        report.put("mpc", {"rows": rows, "partial": m != sizes[-1]})
    return {"rows": rows}


def train(device: torch.device, backend: str, num_envs: int, seconds: float, out: Path,
          iterations: int = 100000, cuda_graph: bool = False) -> dict:
    """PPO on base for about ``seconds`` or ``iterations`` (SIGTERM at the time: the trainer saves at the end of
    its iteration); ``cuda_graph``: each env step replayed from one graph (``scene.cuda_graph``)."""
    run_dir = Path(os.environ.get("TMPDIR", "/tmp")) / f"gpu_check_train_{os.getpid()}"
    cmd = [sys.executable, "-m", "dls_quadruped.learning.train", "--task", "base", "--num-envs", str(num_envs),
           "--iterations", str(iterations), "--device", str(device), "--backend", backend, "--seed", "0",
           "--run-dir", str(run_dir), "--save-every-min", "1", "--set", f"scene.cuda_graph={str(cuda_graph).lower()}"]
    tic = time.perf_counter()
    with open(out / "train.log", "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        try:
            proc.wait(timeout=max(seconds, 1.0))
        except subprocess.TimeoutExpired:
            proc.terminate()  # the trainer saves at the end of its iteration
            try:
                proc.wait(timeout=90)
            except subprocess.TimeoutExpired:
                proc.kill()
    result = {"num_envs": num_envs, "cuda_graph": cuda_graph, "wall_s": time.perf_counter() - tic,
              "returncode": proc.returncode, "run_dir": str(run_dir)}
    ckpts = sorted(run_dir.glob("model_*.pt"), key=lambda p: int(p.stem.split("_")[1])) if run_dir.exists() else []
    if ckpts:
        shutil.copy(ckpts[-1], out / "train_checkpoint.pt")
        result["checkpoint"] = ckpts[-1].name
        try:
            from dls_quadruped.viz import learning_curve

            learning_curve.main([str(run_dir), "--csv", str(out / "learning_curve.csv"),
                                 "--png", str(out / "learning_curve.png")])
            rows = (out / "learning_curve.csv").read_text().splitlines()
            result["iterations"] = len(rows) - 1
            result.update(ppo_throughput(rows, num_envs))
            result["last_row"] = rows[-1]
            result["header"] = rows[0]
        except Exception as err:  # noqa: BLE001 - the checkpoint is there; the curve is a convenience
            result["learning_curve_error"] = f"{type(err).__name__}: {err}"
    return result


def ppo_throughput(csv_rows: list[str], num_envs: int, steps_per_env: int = 24) -> dict:
    """PPO samples/s end to end from a learning curve's rows (header first): the median over iterations after the
    first (which compiles) of collection + update time."""
    header = csv_rows[0].split(",")
    col, upd = header.index("collection_s"), header.index("learning_s")
    times = sorted(float(r.split(",")[col]) + float(r.split(",")[upd]) for r in csv_rows[2:])
    if not times:
        return {}
    median = times[len(times) // 2] if len(times) % 2 else 0.5 * (times[len(times) // 2 - 1] + times[len(times) // 2])
    return {"iteration_s_median": median, "samples_per_s": num_envs * steps_per_env / median}


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(prog="dls_quadruped.bench.gpu_check", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("results/gpu_check"))
    p.add_argument("--budget-s", type=float, default=600.0, help="wall-clock budget of the whole check [s]")
    p.add_argument("--device", default=None, help="cuda (default when available) or cpu (runs on warp-cpu)")
    p.add_argument("--skip", default="", help=f"comma-separated sections to skip, of {', '.join(SECTIONS)}")
    p.add_argument("--train-envs", type=int, default=None, help="robots of the training run (4096 on a GPU)")
    p.add_argument("--env-steps", type=int, default=None, help="timed env steps per throughput row")
    p.add_argument("--train-graph", action="store_true",
                   help="train with each env step replayed from one CUDA graph (scene.cuda_graph)")
    args = p.parse_args(argv)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    if device.type not in ("cuda", "cpu"):
        p.error(f"--device must be cuda or cpu, got {args.device!r}")
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    if skip - set(SECTIONS):
        p.error(f"--skip: unknown sections {sorted(skip - set(SECTIONS))}; allowed: {', '.join(SECTIONS)}")
    try:
        import mujoco_warp  # noqa: F401
    except ImportError as err:
        p.error(f"the GPU check runs the MuJoCo Warp backend, and {err.name} is not installed: make install-gpu "
                "(or make install-offline WHEELHOUSE=...; docs/gpu.md)")
    gpu = device.type == "cuda"
    backend = "cuda" if gpu else "warp-cpu"
    args.out.mkdir(parents=True, exist_ok=True)
    report = Report(args.out / "report.json", args.budget_s)
    report.data.update({"device": str(device), "backend": backend})
    # compiled (the CUDA default) and eager side by side at 4 096 first, then the other sizes, then launched
    big = ([("base", 4096, True, None), ("base", 4096, True, False), ("base", 16384, True, None),
            ("base", 65536, True, None), ("base", 4096, False, None)] if gpu
           else [("base", 4, True, None), ("base", 4, True, False)])
    graph_rows = ([("base", 4096, True, None, True), ("base", 4096, True, None, False),
                   ("base", 16384, True, None, True)] if gpu
                  else [("base", 4, True, None, True), ("base", 4, True, None, False)])
    rough_n = 4096 if gpu else 4
    steps = args.env_steps or (60 if gpu else 3)
    # a compiled step recompiles for the first few reset batch sizes (then marks them dynamic): enough warm-up
    # steps keep those recompiles out of the timed window (docs/gpu.md)
    warmup = WARMUP_STEPS if gpu else 3
    plan = [
        ("versions", lambda: versions(device)),
        ("compile", lambda: compile_times(backend, device, ("flat",))),
        # the step replayed from one graph (scene.cuda_graph): agreement first, then its rate beside the default's
        ("graph", lambda: {"agreement": graph_agreement(backend, device, 256 if gpu else 4, 60 if gpu else 8),
                           "rows": env_throughput(backend, device, graph_rows, steps, report,
                                                  reserve_s=0.6 * args.budget_s, section="graph", warmup=warmup)}),
        ("trajectories", lambda: trajectories(backend)),
        ("syncs", lambda: syncs(backend, device, 256 if gpu else 4, 40 if gpu else 4, warmup)),
        ("launches", lambda: {"compiled": launches(backend, device, 4, 12, compile=True),
                              "eager": launches(backend, device, 4, 12, compile=False)}),
        ("faults", lambda: faults(backend, device, 64 if gpu else 8)),
        ("env", lambda: {"rows": env_throughput(backend, device, big, steps, report,
                                                 reserve_s=0.35 * args.budget_s, warmup=warmup)}),
        ("gpu_busy", lambda: {"eager_step": gpu_busy(backend, device, 4096, 10, warmup),
                              "graph_step": gpu_busy(backend, device, 4096, 10, warmup, cuda_graph=True)}),
        ("mpc", lambda: mpc_rows(device, (10000, 100000) if gpu else (500,), 20 if gpu else 2, report)),
        ("rough", lambda: {"compile": compile_times(backend, device, ("rough",))["rough"],
                           "rows": env_throughput(backend, device, [("rough", rough_n, True, None)], steps, report,
                                                  reserve_s=0.2 * args.budget_s, section="rough",
                                                  warmup=warmup)}),
        ("train", lambda: train(device, backend, args.train_envs or (4096 if gpu else 8),
                                report.left() - 100 if gpu else 900.0, args.out, 100000 if gpu else 1,
                                cuda_graph=args.train_graph)),
    ]
    for name, run in plan:
        if name in skip:
            continue
        if name != "train" and report.left() < 60:
            report.put(name, {"skipped": "budget"})
            continue
        tic = time.perf_counter()
        try:
            value = run()
        except Exception as err:  # noqa: BLE001 - a broken section is a finding; the next one still runs
            value = {"error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc()[-2000:]}
        report.put(name, {**value, "section_s": round(time.perf_counter() - tic, 1)})
    print(f"wrote {report.path}")


if __name__ == "__main__":
    run_cli(main)
