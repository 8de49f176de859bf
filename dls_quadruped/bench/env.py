"""Backend throughput benchmark (``make bench``, first part).

Measures, in one run on the same cores:

* ``raw``: open-loop ``mujoco.batch.Batch`` physics (all threads, constant standing
  torques, no controller) — the ceiling; also with the robot's self-collision switched off
  (``conaffinity = 0`` on its geoms), which prices the self-collision pairs;
* ``python loop``: the alternative to ``Batch``, ``mj_step`` on one ``MjData`` per robot in a
  Python loop (GIL held, one core);
* ``backend``: the full backend (physics + Pinocchio + low-level control at every physics
  step), worker processes (one per core) and in-process, standing on flat ground with the
  references held (the high-level producer is not part of this number).

Writes ``results/bench/env_throughput.json`` and prints a markdown table for
``docs/benchmarks.md``. Usage: ``python -m dls_quadruped.bench.env [--sizes 1024 4096]``.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco.batch import Batch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.control.dynamics import LegDynamics
from dls_quadruped.core.progress import progress
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend


def _standing_torques(model: mujoco.MjModel) -> np.ndarray:
    """Stance torques -J^T F at the home pose with the weight shared by the four feet, (12,)."""
    dyn = LegDynamics().compute(model.key_qpos[:1], np.zeros((1, model.nv)))
    force = np.array([0.0, 0.0, C.WEIGHT / 4])
    tau = -np.einsum("lij,i->lj", dyn.J_leg[0], force).reshape(12)
    return np.clip(tau, -C.TORQUE_LIMITS, C.TORQUE_LIMITS)


def raw_physics(model: mujoco.MjModel, n: int, seconds: float) -> float:
    """Open-loop Batch physics steps per second (all threads)."""
    batch = Batch(model, n, nthread=0)
    batch.reset(keyframe=np.zeros(n, dtype=np.int32))
    batch.bind("ctrl")[:] = _standing_torques(model)
    batch.step(nstep=4)  # warm-up
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        batch.step(nstep=4)
        steps += 4
    return n * steps / (time.perf_counter() - t0)


def without_self_collision(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` whose robot geoms collide with the ground only (the pre-issue-8 robot)."""
    m = model.__copy__()
    robot = (m.geom_bodyid != 0) & (m.geom_contype != 0)
    m.geom_conaffinity[robot] = 0
    return m


def loop_physics(model: mujoco.MjModel, n: int, seconds: float) -> float:
    """The alternative to ``Batch``: a Python loop of ``mj_step`` over n MjData (one thread, GIL held)."""
    datas = [mujoco.MjData(model) for _ in range(n)]
    tau = _standing_torques(model)
    for d in datas:
        mujoco.mj_resetDataKeyframe(model, d, 0)
        d.ctrl[:] = tau
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for d in datas:
            mujoco.mj_step(model, d)
        steps += 1
    return n * steps / (time.perf_counter() - t0)


def full_backend(model: mujoco.MjModel, n: int, seconds: float, workers: int) -> float:
    """Full-backend physics steps per second (physics + Pinocchio + low-level control)."""
    with make_backend("cpu", model, n, SimConfig(num_workers=workers)) as sim:
        sim.reset(torch.arange(n), **home_state(n, 0, 0.0))
        sim.step(4)  # warm-up
        steps, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            sim.step(4)
            steps += 4
        return n * steps / (time.perf_counter() - t0)


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--seconds", type=float, default=8.0, help="measurement time per configuration")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args()
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    cores = os.cpu_count() or 1
    rows = []
    for n in progress(args.sizes, desc="robot counts", unit="size"):
        raw = raw_physics(model, n, args.seconds)
        raw_noself = raw_physics(without_self_collision(model), n, args.seconds)
        loop = loop_physics(model, n, args.seconds)
        workers = full_backend(model, n, args.seconds, workers=-1)
        inproc = full_backend(model, n, args.seconds, workers=0)
        rows.append({"num_envs": n, "raw_steps_per_s": raw, "raw_no_self_collision_steps_per_s": raw_noself,
                     "self_collision_cost": 1.0 - raw / raw_noself, "python_loop_mj_step_per_s": loop,
                     "backend_workers_steps_per_s": workers,
                     "backend_inprocess_steps_per_s": inproc, "ratio_workers_to_raw": workers / raw,
                     "ratio_inprocess_to_raw": inproc / raw})
        print(f"N={n}: raw {raw:,.0f}/s (without self-collision {raw_noself:,.0f}/s), (python mj_step loop "
              f"{loop:,.0f}/s), backend ({cores} workers) {workers:,.0f}/s ({workers / raw:.2f} x raw), "
              f"in-process {inproc:,.0f}/s ({inproc / raw:.2f} x raw)", flush=True)
    result = {
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": cores,
                    "python": platform.python_version(),
                    "torch": torch.__version__, "mujoco": mujoco.__version__},
        "seconds_per_config": args.seconds,
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = args.out / "env_throughput.json.tmp"
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(args.out / "env_throughput.json")
    print("\n| N | raw Batch physics [steps/s] | raw, no self-collision | python mj_step loop [steps/s] | full "
          "backend, workers [steps/s] | ratio "
          "| full backend, in-process [steps/s] | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['num_envs']} | {r['raw_steps_per_s']:,.0f} | {r['raw_no_self_collision_steps_per_s']:,.0f} | "
              f"{r['python_loop_mj_step_per_s']:,.0f} | {r['backend_workers_steps_per_s']:,.0f} | "
              f"{r['ratio_workers_to_raw']:.2f} | {r['backend_inprocess_steps_per_s']:,.0f} | "
              f"{r['ratio_inprocess_to_raw']:.2f} |")


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
