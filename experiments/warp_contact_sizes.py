"""Contacts and constraint rows per robot that each task uses on the MuJoCo Warp backend (docs/gpu.md "Contact and
constraint sizes"): the sizes of ``scene.nconmax`` / ``scene.njmax`` in the task files are these with headroom.

Each task's env runs on ``warp-cpu`` with generous sizes (no overflow can cut the count), robots spread over every
terrain row, and random actions large enough that robots stumble, fall and are reset; after every physics step the
backend's ``collision_stats`` gives the most contacts, contact candidates and constraint rows in one world. Writes
``results/warp_contact_sizes.csv``.

    python -m experiments.warp_contact_sizes --tasks base rough speed climb --num-envs 16 --steps 100
"""

from __future__ import annotations

import csv
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv

FIELDS = ("contacts_max", "candidates_max", "nefc_max", "pairs_tested_max")


def measure(task: str, num_envs: int, steps: int, action_scale: float, seed: int = 0) -> dict[str, float]:
    """Largest per-world use over ``steps`` policy steps of random actions (every physics step looked at)."""
    from dls_quadruped.sim.warp_collision import (
        ALLOCATION_OVERFLOWS,  # needs the [gpu] extra: not at import
    )

    # every row of the terrain from the start (the curriculum's hardest rows too), generous sizes
    overrides = {"scene": {"backend": "warp-cpu", "num_workers": 0, "nconmax": 256, "njmax": 1024,
                           "max_init_level": 99}}
    env = LocomotionEnv(load_task(task, overrides=overrides), num_envs=num_envs, seed=seed, verbose=False)
    sim, worst = env.scene.sim, dict.fromkeys(FIELDS, 0)
    worst["resets"] = 0
    step = sim.step

    def step_and_record(num_physics_steps: int = 1):
        for _ in range(num_physics_steps):  # one at a time: the stats are those of the last physics step
            state = step(1)
            stats = sim.collision_stats()
            assert not stats["overflow"] & ALLOCATION_OVERFLOWS, stats  # nothing cut off: the counts are complete
            for k in FIELDS:
                worst[k] = max(worst[k], stats[k])
        return state

    sim.step = step_and_record
    g = torch.Generator().manual_seed(seed)
    try:
        for _ in range(steps):
            _, _, dones, _ = env.step(action_scale * torch.randn(num_envs, 28, generator=g))
            worst["resets"] += int(dones.sum())
    finally:
        env.close()
    return worst


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=["base", "rough", "speed", "climb"])
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--steps", type=int, default=100, help="policy steps (50 Hz)")
    p.add_argument("--action-scale", type=float, default=1.0)
    p.add_argument("--out", type=Path, default=Path("results/warp_contact_sizes.csv"))
    args = p.parse_args(argv)
    rows = []
    for task in args.tasks:
        row = {"task": task, "num_envs": args.num_envs, "steps": args.steps, "action_scale": args.action_scale,
               **measure(task, args.num_envs, args.steps, args.action_scale)}
        print(row, flush=True)
        rows.append(row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    run_cli(main)
