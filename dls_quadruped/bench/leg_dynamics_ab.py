"""RL env steps/s with the cpu backend's two leg-dynamics sources side by side, in one process.

Builds ``base`` and ``rough`` with ``scene.leg_dynamics: pinocchio`` (the default) and ``mujoco`` (MuJoCo's M and
bias forces from a persistent ``Batch`` + batched torch kinematics, ``sim/shard.py``) and steps them in turn, a few
RL steps per env per round with random actions (std 1, resets included), so machine load hits all of them alike;
prints and writes (``results/bench/leg_dynamics_ab.json``) the median RL steps/s and the ratio mujoco / pinocchio.
With in-process shards (``--workers 0``) it also splits the backend: the leg terms (``Shard._dynamics_terms``),
``Batch.step`` (which on the mujoco path also computes the next step's position/velocity stages) and the
low-level controller, per env step. Usage::

    python -m dls_quadruped.bench.leg_dynamics_ab --sizes 256 1024 --workers 0 2
"""

from __future__ import annotations

import os
import statistics
import time
from collections import defaultdict
from pathlib import Path

import torch

from dls_quadruped.bench.terrain_ab import interleaved_rates, make_env
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model

MODES = ("pinocchio", "mujoco")


def _timed(obj, name: str, acc: dict, key: str) -> None:
    """Wrap ``obj.name`` (an instance attribute from now on) to add its wall time to ``acc[key]``."""
    inner = getattr(obj, name)

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            acc[key] += time.perf_counter() - t0

    setattr(obj, name, wrapper)


def measure(tasks: list[str], n: int, workers: int, rounds: int, steps: int) -> dict:
    """Median RL steps/s per (task, mode) over interleaved rounds; with ``workers == 0`` the backend split too."""
    envs = {(t, m): make_env(t, n, overrides={"scene": {"num_workers": workers, "leg_dynamics": m}})
            for t in tasks for m in MODES}
    split: dict = {k: defaultdict(float) for k in envs}
    if workers == 0:
        for k, env in envs.items():
            shard = env.scene.sim.in_process_shard
            _timed(shard, "_dynamics_terms", split[k], "leg_terms")
            _timed(shard.batch, "step", split[k], "batch_step")
            _timed(shard.controller, "compute", split[k], "controller")

    def clear_split() -> None:  # the warm-up's calls are not timed
        for acc in split.values():
            acc.clear()

    rates = interleaved_rates(envs, n, rounds, steps, desc=f"N={n} workers={workers}", before_rounds=clear_split)
    out = {}
    for t in tasks:
        row = {}
        for m in MODES:
            r = rates[(t, m)]
            row[m] = {"median": statistics.median(r), "min": min(r), "max": max(r)}
            if workers == 0:
                row[m]["ms_per_env_step"] = {p: 1e3 * v / (rounds * steps) for p, v in split[(t, m)].items()}
        row["speedup"] = row["mujoco"]["median"] / row["pinocchio"]["median"]
        out[t] = row
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["base", "rough"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=3, help="RL steps per env per round")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    result = {"cpu": cpu_model(), "load_avg_before": os.getloadavg(), "rounds": args.rounds, "steps": args.steps,
              "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "rows": []}
    for n in args.sizes:
        for w in args.workers:
            row = measure(args.tasks, n, w, args.rounds, args.steps)
            result["rows"].append({"N": n, "workers": w, "tasks": row, "load_avg": os.getloadavg()})
            for t, r in row.items():
                extra = ""
                if w == 0:
                    extra = "; ms/env step " + ", ".join(
                        f"{m}: " + " ".join(f"{p} {v:.1f}" for p, v in r[m]["ms_per_env_step"].items()) for m in MODES)
                print(f"N={n} workers={w} {t}: pinocchio {r['pinocchio']['median']:,.0f}, mujoco "
                      f"{r['mujoco']['median']:,.0f} RL steps/s (x{r['speedup']:.2f}){extra}", flush=True)
    result["load_avg_after"] = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out / "leg_dynamics_ab.json")
    return result


if __name__ == "__main__":
    run_cli(main)
