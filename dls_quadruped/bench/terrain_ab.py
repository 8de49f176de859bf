"""Rough-task RL throughput with two terrain implementations side by side, in one process.

Builds the envs ``base``, ``rough_whole_terrain`` (every robot on the whole terrain:
``scene.terrain_regions: false``), ``rough`` (per-robot terrain regions, the default, ``sim/regions.py``)
and, with ``--baseline-terrain``, ``rough`` with a terrain module given as a file (e.g. an older
``sim/terrain.py`` from git), and steps them in turn, a few RL steps per env per round with random
actions (std 1), so machine load hits all of them alike; prints and writes
(``results/bench/terrain_ab.json``) the median RL steps/s and the ratio to base. The other module
must provide ``TerrainConfig`` and ``build_scene(cfg) -> (model, terrain)`` with
``terrain.height_at``/``tile_origins_w``/``num_rows``/``num_cols``; config fields it lacks keep its
defaults. Usage::

    python -m dls_quadruped.bench.terrain_ab --sizes 1024
    git show 705da13:dls_quadruped/sim/terrain.py > /tmp/old_terrain.py
    python -m dls_quadruped.bench.terrain_ab --baseline-terrain /tmp/old_terrain.py --sizes 1024 4096
"""

from __future__ import annotations

import importlib.util
import os
import statistics
import sys
import time
from pathlib import Path

import torch

import dls_quadruped.envs.managers.scene as scene_module
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.core.progress import progress
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv


def load_terrain_module(path: Path):
    """Import a terrain implementation from a file under a private module name."""
    name = f"_terrain_baseline_{abs(hash(str(path)))}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"terrain_ab: error: cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def make_env(task: str, n: int, terrain_module=None, overrides: dict | None = None) -> LocomotionEnv:
    """A ``LocomotionEnv`` (task file + ``overrides``); with ``terrain_module``, its scene is built by that
    module instead."""
    current = scene_module.build_scene
    if terrain_module is not None:
        fields = terrain_module.TerrainConfig.__dataclass_fields__

        def build(cfg):
            kept = {k: getattr(cfg, k) for k in cfg.__dataclass_fields__ if k in fields}
            return terrain_module.build_scene(terrain_module.TerrainConfig(**kept))

        scene_module.build_scene = build
    try:
        return LocomotionEnv(load_task(task, overrides), num_envs=n, verbose=False)
    finally:
        scene_module.build_scene = current


def interleaved_rates(envs: dict, n: int, rounds: int, steps: int, desc: str,
                      before_rounds=None) -> dict[object, list[float]]:
    """RL steps/s of every env of ``envs`` (each with ``n`` robots, random actions) in ``rounds`` rounds of
    ``steps`` steps, the envs taking turns within a round so that a change of machine load hits all of
    them alike; one warm-up round first, then ``before_rounds()`` if given. Closes the envs."""
    gen = torch.Generator().manual_seed(0)
    rates: dict[object, list[float]] = {k: [] for k in envs}
    try:
        for env in envs.values():
            env.reset()
            for _ in range(steps):  # warm-up
                env.step(torch.randn(n, 28, generator=gen))
        if before_rounds is not None:
            before_rounds()
        for _ in progress(range(rounds), desc=desc, unit="round", leave=False):
            for name, env in envs.items():
                t0 = time.perf_counter()
                for _ in range(steps):
                    env.step(torch.randn(n, 28, generator=gen))
                rates[name].append(n * steps / (time.perf_counter() - t0))
    finally:
        for env in envs.values():
            env.close()
    return rates


def measure(n: int, rounds: int, steps: int, baseline) -> dict[str, dict[str, float]]:
    """Median RL steps/s per env over interleaved rounds."""
    envs = {"base": make_env("base", n),
            "rough_whole_terrain": make_env("rough", n, overrides={"scene": {"terrain_regions": False}}),
            "rough": make_env("rough", n)}
    if baseline is not None:
        envs["rough_baseline_terrain"] = make_env("rough", n, baseline, {"scene": {"terrain_regions": False}})
    rates = interleaved_rates(envs, n, rounds, steps, desc=f"N={n} rounds")
    base = statistics.median(rates["base"])
    return {k: {"median": statistics.median(v), "min": min(v), "max": max(v),
                "ratio_to_base": statistics.median(v) / base}
            for k, v in rates.items()}


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-terrain", type=Path, help="a terrain.py to compare against as well")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=3, help="RL steps per env per round")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    if args.baseline_terrain is not None and not args.baseline_terrain.is_file():
        parser.error(f"--baseline-terrain {args.baseline_terrain}: no such file")
    torch.set_num_threads(1)
    baseline = None if args.baseline_terrain is None else load_terrain_module(args.baseline_terrain)
    result = {"baseline_terrain": None if baseline is None else str(args.baseline_terrain), "cpu": cpu_model(),
              "load_avg_before": os.getloadavg(), "rounds": args.rounds, "steps": args.steps, "rows": {}}
    for n in args.sizes:
        result["rows"][n] = measure(n, args.rounds, args.steps, baseline)
        r = result["rows"][n]
        print(f"N={n}: " + ", ".join(f"{k} {v['median']:,.0f} ({v['ratio_to_base']:.2f} x base)" for k, v in r.items())
              + " RL steps/s", flush=True)
    result["load_avg_after"] = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out / "terrain_ab.json")
    return result


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
