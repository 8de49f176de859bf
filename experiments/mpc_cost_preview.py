"""A quick look, not the plan's evaluation: the trajectory cost c of deterministic horizon policies on base_mpc_cost.

Each policy (a student program or a training run's ``exported/policy.pt2``, both obs -> the encoded horizon) drives
the same env (same seed, so the same commands) for ``--steps`` policy steps; after ``--settle`` steps every robot's c
(``mpc_trajectory_cost``, no clip) and its planar velocity error are collected. Episodes of the training
distribution, not the evaluation's validation or test split: exploratory, no interval.

    python -m experiments.mpc_cost_preview docs/policies/base_recipe_student_first_spline_h10.pt2 \
        runs/base_mpc_cost/w0.1_s0/exported/policy.pt2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp import rewards
from dls_quadruped.envs.mdp.observations import base_lin_vel
from dls_quadruped.learning.policy_file import load_module


def preview(policy_path: Path, num_envs: int, steps: int, settle: int, seed: int) -> dict[str, float]:
    """c quartiles and mean, mean |v_xy - cmd| [m/s] and falls of one policy."""
    policy = load_module(policy_path)
    env = LocomotionEnv(load_task("base_mpc_cost", overrides={"scene": {"num_workers": 0}}), num_envs=num_envs,
                        seed=seed, verbose=False)
    try:
        obs, _ = env.reset()
        costs, errors, falls = [], [], 0
        for i in range(steps):
            with torch.no_grad():
                out = policy(obs["policy"])
            obs, _, dones, extras = env.step(out[0] if isinstance(out, tuple) else out)
            falls += int((dones.bool() & ~extras["time_outs"].bool()).sum())
            if i >= settle:
                costs.append(rewards.mpc_trajectory_cost(env, clip=1e9, split_every=1000))
                errors.append(torch.linalg.vector_norm(base_lin_vel(env)[:, :2] - env.command_manager.command[:, :2],
                                                       dim=-1))
    finally:
        env.close()
    c = torch.cat(costs)
    q = torch.quantile(c, torch.tensor([0.25, 0.5, 0.75])).tolist()
    return {"c_q25": q[0], "c_median": q[1], "c_q75": q[2], "c_mean_clip100": float(c.clamp(max=100).mean()),
            "vel_error": float(torch.cat(errors).mean()), "falls": falls}


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", type=Path, nargs="+")
    p.add_argument("--num-envs", type=int, default=128)
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--settle", type=int, default=100)
    p.add_argument("--seed", type=int, default=123)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    out = {}
    for path in args.policies:
        r = out[str(path)] = preview(path, args.num_envs, args.steps, args.settle, args.seed)
        print(f"{path}: c median {r['c_median']:.2f} [IQR {r['c_q25']:.2f}, {r['c_q75']:.2f}], mean (clip 100) "
              f"{r['c_mean_clip100']:.2f}; |v - cmd| {r['vel_error']:.3f} m/s; falls {r['falls']}")
    return out


if __name__ == "__main__":
    run_cli(main)
