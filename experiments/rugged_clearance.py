"""Diagnostic: a policy on one row of rugged tiles without any disturbance -- falls, when and why.

    python -m experiments.rugged_clearance --policy docs/policies/rough_actor.pt --difficulty 0.5 0.7 1.0

The survival task's terrain and observation noise (``eval/survival.py``) with its rugged type only, one row
at each ``--difficulty`` (a fraction of the rough task's range: rugged amplitude a = 1 + 7 d cm), events
reduced to the start pose (``strength = 0``: no friction spread, wrench or pushes), simple-task commands,
seed-fixed. Prints, per difficulty, the robots that fell within ``--seconds``, their median time to the
fall and the termination terms that ended them. docs/experiments/experts.md ("Rugged tiles past ±4 cm") quotes it:
the swing apex is 6 cm above the higher of lift-off and touch-down, while neighbouring rugged vertices
differ by up to 2a.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, run_cli


def run(policy: Path, difficulty: float, robots: int, seconds: float, seed: int) -> dict:
    """One rugged row at ``difficulty``; {"amplitude_m", "fell", "robots", "median_fall_s", "terms"}."""
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.eval.policy import load_policy
    from dls_quadruped.eval.scenario import EvalOptions, replace_sections
    from dls_quadruped.eval.survival import survival_task
    from dls_quadruped.eval.sweep import place_on_rows
    from dls_quadruped.eval.velocity_tracking import simple_commands

    opts = EvalOptions(episodes=robots, seed=seed, num_workers=0)
    task = survival_task(simple_commands(robots, seed), opts, rows=1, hard=difficulty, strength=0.0)
    terrain = {**task.data["terrain"], "types": ["rugged"]}  # one row: its difficulty is the range's start
    task = replace_sections(task, {"terrain": terrain}, source="<rugged_clearance: rugged only>")
    env = LocomotionEnv(task, num_envs=robots, seed=seed, verbose=False)
    try:
        place_on_rows(env, np.zeros(robots, dtype=int))
        act = load_policy(policy, env)
        obs = env.get_observations()
        alive = torch.ones(robots, dtype=torch.bool)
        fall_s, terms = [], Counter()
        with torch.no_grad():
            for k in range(round(seconds / env.step_dt)):
                obs, _, dones, _ = env.step(act(obs))
                ended = dones.bool() & alive & ~env.termination_manager.time_outs
                for i in torch.nonzero(ended).flatten().tolist():
                    fall_s.append((k + 1) * env.step_dt)
                    terms["+".join(n for n, v in env.termination_manager.term_dones.items() if v[i])] += 1
                alive &= ~dones.bool()
    finally:
        env.close()
    return {"amplitude_m": float(terrain["rugged_amplitude"][0]), "fell": len(fall_s), "robots": robots,
            "median_fall_s": float(np.median(fall_s)) if fall_s else None, "terms": dict(terms)}


def main(argv: list[str] | None = None) -> list[dict]:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", type=Path, default=Path("docs/policies/rough_actor.pt"))
    p.add_argument("--difficulty", type=float, nargs="+", default=[0.5, 0.7, 1.0],
                   help="fractions of the rough task's rugged range, each in [0, 1]")
    p.add_argument("--robots", type=int, default=24)
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    bad = [d for d in args.difficulty if not 0.0 <= d <= 1.0]
    if bad:
        p.error(f"argument --difficulty: each must be in [0, 1], got {bad}")
    if args.robots < 1 or args.seconds <= 0:
        p.error(f"--robots must be >= 1 and --seconds > 0, got {args.robots} and {args.seconds}")
    torch.set_num_threads(1)
    out = []
    for d in args.difficulty:
        r = run(args.policy, d, args.robots, args.seconds, args.seed)
        med = "-" if r["median_fall_s"] is None else f"{r['median_fall_s']:.2f} s"
        print(f"difficulty {d:g} (rugged +-{100 * r['amplitude_m']:.1f} cm): fell {r['fell']}/{r['robots']} within "
              f"{args.seconds:g} s, median fall at {med}, ended by {r['terms']}", flush=True)
        out.append({"difficulty": d, **r})
    return out


if __name__ == "__main__":
    run_cli(main)
