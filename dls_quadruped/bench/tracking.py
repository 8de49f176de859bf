"""Simple-task evaluation of a trained policy (issue 4 item 8): constant forward command, flat ground.

    python -m dls_quadruped.bench.tracking --checkpoint runs/base/<run>/model_199.pt [--speed 0.5]

Runs the ``base`` task (flat, no noise, no perturbation) with the command fixed to
(v_x, v_y, omega_z) = (speed, 0, 0) for every env, the deterministic policy (action mean), for
``--steps`` policy steps (50 per s; fewer than the 750 of an episode, so no time-out happens).
Reports, over all envs and the steps after ``--settle`` (start-up transient excluded):

* ``mean_vx_error``: mean |v_x,b - speed| [m/s] (forward-velocity error, base frame);
* ``mean_vxy_error``: mean |v_xy,b - v_cmd,xy| [m/s];
* ``falls``: envs terminated by a non-time-out term (base/hip/thigh contact, tilt > 45 deg, divergence).

Writes ``--out`` (JSON) if given.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp.observations import base_lin_vel
from dls_quadruped.learning.runner import AtomicOnPolicyRunner, runner_config


def forward_command_task(task: str, speed: float, num_workers: int):
    """The task with every command fixed to (speed, 0, 0) (``uniform_velocity`` with point ranges)."""
    params = {"lin_vel_x": [speed, speed], "lin_vel_y": [0.0, 0.0], "ang_vel_z": [0.0, 0.0],
              "standing_fraction": 0.0, "max_speed": None}
    return load_task(task, overrides={"scene": {"num_workers": num_workers},
                                      "commands": {"base_velocity": {"func": "uniform_velocity", "params": params}}})


def evaluate(checkpoint: Path, task: str = "base", speed: float = 0.5, num_envs: int = 32, steps: int = 400,
             settle: int = 50, num_workers: int = 0) -> dict:
    cfg = forward_command_task(task, speed, num_workers)
    env = LocomotionEnv(cfg, num_envs=num_envs, verbose=False)
    try:
        runner = AtomicOnPolicyRunner(env, runner_config(cfg.data["agent"]), log_dir=None)
        runner.load(str(checkpoint))
        policy = runner.get_inference_policy()
        obs = env.get_observations()
        fell = torch.zeros(num_envs, dtype=torch.bool)
        ex, exy = [], []
        with torch.inference_mode():
            for k in range(steps):
                obs, _, dones, extras = env.step(policy(obs))
                fell |= dones.bool() & ~extras["time_outs"].bool()
                if k >= settle:
                    # velocity after the step, before reset (reset envs are excluded once fallen)
                    v = base_lin_vel(env)[:, :2]
                    ok = ~fell
                    ex.append((v[ok, 0] - speed).abs())
                    exy.append(torch.linalg.vector_norm(v[ok] - env.command_manager.command[ok, :2], dim=-1))
        ex_all, exy_all = torch.cat(ex), torch.cat(exy)
        return {"checkpoint": str(checkpoint), "task": task, "speed": speed, "num_envs": num_envs, "steps": steps,
                "settle_steps": settle, "mean_vx_error": float(ex_all.mean()), "mean_vxy_error": float(exy_all.mean()),
                "falls": int(fell.sum())}
    finally:
        env.close()


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", type=Path, required=True)
    p.add_argument("--task", default="base")
    p.add_argument("--speed", type=float, default=0.5)
    p.add_argument("--num-envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--settle", type=int, default=50)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    res = evaluate(args.checkpoint, args.task, args.speed, args.num_envs, args.steps, args.settle)
    print(json.dumps(res, indent=2))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    main()
