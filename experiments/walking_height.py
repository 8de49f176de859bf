"""How high each expert carries its CoM while walking: the MPC's height reference to match it (``--com-height``).

    python -m experiments.walking_height --variant recipe            # base, speed and rough, retrained
    python -m experiments.walking_height --variant thesis --tasks base
    python -m experiments.walking_height --policy base_s1=docs/policies/expert_seeds/base_thesis_s1_it449.pt2

The sampling MPC's cost pulls the CoM towards one height (``mpc.srbd.com_height_reference``, ~0.324 m: the RL
task's base height target). The RL reward weighs height little (thesis 7.3.7), so an expert may walk elsewhere,
and an MPC warm-started by its student then fights the plan it was given. This plays each expert alone on the
base task (flat, commands resampled within +-1 m/s, no disturbance) on **validation** episodes (seed + 1 000 003,
``eval.scenario.split_seed``; never the test episodes the experiments report on) and measures the CoM's height
above the ground: the base origin plus the CoM offset turned into the world frame, averaged over the robots that
stand and the steps after the first ``--settle`` seconds. Writes ``<out>/walking_height.json`` and prints one line
per expert with the value to pass as ``--com-height``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.rotations import quat_rotate
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import split_seed
from dls_quadruped.learning.policy_file import load_module
from dls_quadruped.mpc.srbd import com_height_reference, robot_srbd_model
from experiments.rl_common import POLICY_DIR, REPO, VARIANTS, Policies


def walking_height(policy: torch.nn.Module, robots: int, seconds: float, settle: float, seed: int) -> dict:
    """Mean and spread of the CoM height [m] above flat ground of ``policy`` walking the base task."""
    env = LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 0}}), num_envs=robots, seed=seed,
                        verbose=False)
    offset_b = torch.tensor(robot_srbd_model().com_offset_b, dtype=torch.float32).expand(robots, 3)
    obs, _ = env.reset(seed=seed)
    up = torch.ones(robots, dtype=torch.bool)
    heights = []
    steps, skip = round(seconds / env.step_dt), round(settle / env.step_dt)
    with torch.no_grad():
        for t in range(steps):
            obs, _, dones, _ = env.step(policy(obs["policy"]))
            up &= dones == 0
            if t >= skip:
                s = env.state
                heights.append(s.base_pos_w[:, 2] + quat_rotate(s.base_quat_w, offset_b)[:, 2])
    env.close()
    h = torch.stack(heights)[:, up]  # (steps, robots that stood throughout)
    per_robot = h.mean(0)
    return {"com_height_m": float(per_robot.mean()) if len(per_robot) else float("nan"),
            "robot_sd_m": float(per_robot.std()) if len(per_robot) > 1 else 0.0,
            "step_sd_m": float(h.std(0).mean()) if len(per_robot) else float("nan"),
            "robots_standing": int(up.sum()), "robots": robots}


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", choices=sorted(VARIANTS), default="recipe")
    p.add_argument("--tasks", nargs="*", default=["base", "speed", "rough"],
                   choices=["base", "speed", "rough", "climb"])
    p.add_argument("--policy-dir", type=Path, default=POLICY_DIR)
    p.add_argument("--robots", type=int, default=64)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--settle", type=float, default=2.0, help="seconds left out at the start [s]")
    p.add_argument("--seed", type=int, default=0, help="the test seed; the validation episodes are its split")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / "walking_height")
    p.add_argument("--policy", nargs="*", default=None, metavar="NAME=FILE",
                   help="these base-task experts (NAME=FILE each) instead of --variant's --tasks")
    args = p.parse_args(argv)
    named = {}
    for item in args.policy or ():
        name, sep, file = item.partition("=")
        if not sep or not name or not file:
            p.error(f"--policy takes NAME=FILE, got {item!r}")
        if not Path(file).is_file():
            p.error(f"--policy {name}: no file {file}")
        named[name] = Path(file)
    if not 0 <= args.settle < args.seconds:
        p.error(f"--settle must be in [0, --seconds = {args.seconds:g}), got {args.settle:g}")
    torch.set_num_threads(1)
    policies = Policies(args.policy_dir, args.variant)
    seed = split_seed(args.seed, "validation")
    out = {"variant": args.variant, "seed": args.seed, "validation_seed": seed, "robots": args.robots,
           "seconds": args.seconds, "settle_s": args.settle, "mpc_default_com_height_m": com_height_reference(),
           "experts": {}}
    for task, path in (named.items() if named else ((t, policies.expert(t)) for t in args.tasks)):
        if not path.is_file():
            print(f"[walking_height] {task}: {path} not found, skipped", flush=True)
            continue
        res = walking_height(load_module(path), args.robots, args.seconds, args.settle, seed)
        out["experts"][task] = {"path": str(path), **res}
        print(f"[walking_height] {task} ({path.name}): CoM {res['com_height_m']:.4f} m (robots sd "
              f"{res['robot_sd_m']:.4f}, over time {res['step_sd_m']:.4f}; {res['robots_standing']}/{args.robots} "
              f"stood); the MPC's default reference {com_height_reference():.4f} m", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json({**out, **provenance()}, args.out / "walking_height.json", indent=1)
    print(json.dumps({t: round(e["com_height_m"], 4) for t, e in out["experts"].items()}))
    return out


if __name__ == "__main__":
    main()
