"""Train a PPO policy on a task with rsl-rl-lib.

    python -m dls_quadruped.learning.train --task rough --num-envs 64 --iterations 100 --device cpu --seed 0
    python -m dls_quadruped.learning.train --task rough --resume          # continue the latest run

Checkpoints every ``agent.save_interval`` iterations (``--save-interval`` overrides), written
atomically; ``--resume`` reloads the newest checkpoint of the newest run (or of ``--run-dir``) and
continues for ``--iterations`` more. At the end the actor is exported to TorchScript and ONNX.
Multi-GPU: launch with ``torchrun --nproc_per_node=G -m dls_quadruped.learning.train --device cuda``
(each process takes ``cuda:$LOCAL_RANK``);
rsl-rl-lib reads WORLD_SIZE/RANK itself (see docs/train.md; untested here, no GPUs).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    export_policy,
    latest_checkpoint,
    latest_run,
    runner_config,
    write_yaml,
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="base", help="task name in tasks/ or a YAML path")
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--iterations", type=int, default=None, help="PPO iterations (default: agent.max_iterations)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="continue from the newest checkpoint")
    p.add_argument("--run-dir", type=Path, default=None, help="run directory (default: <log-root>/<task>/<time>)")
    p.add_argument("--log-root", type=Path, default=Path("runs"))
    p.add_argument("--save-interval", type=int, default=None)
    p.add_argument("--num-workers", type=int, default=None, help="simulator worker processes (scene.num_workers)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> Path:
    """Train; returns the run directory."""
    args = parse_args(argv)
    if args.device == "cuda" and "LOCAL_RANK" in os.environ:  # torchrun: one GPU per process
        args.device = f"cuda:{os.environ['LOCAL_RANK']}"
    overrides = {"scene": {"num_workers": args.num_workers}} if args.num_workers is not None else None
    task = load_task(args.task, overrides=overrides)
    task_dir = args.log_root / task.name
    resume_from = None
    if args.resume:
        run_dir = args.run_dir or latest_run(task_dir)
        resume_from = latest_checkpoint(run_dir) if run_dir is not None else None
        if resume_from is None:
            raise SystemExit(f"--resume: no checkpoint found under {args.run_dir or task_dir}")
    else:
        run_dir = args.run_dir or task_dir / time.strftime("%Y-%m-%d_%H-%M-%S")
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(args.seed)
    env = LocomotionEnv(task, num_envs=args.num_envs, device=args.device, seed=args.seed, run_dir=run_dir)
    cfg = runner_config(task.data["agent"], args.iterations, args.seed)
    if args.save_interval is not None:
        cfg["save_interval"] = args.save_interval
    write_yaml(cfg, run_dir / "agent.yaml")
    runner = AtomicOnPolicyRunner(env, cfg, log_dir=str(run_dir), device=args.device)
    if resume_from is not None:
        runner.load(str(resume_from))
        # model_<it>.pt holds the state after iteration <it>: continue with the next one
        runner.current_learning_iteration += 1
        print(f"[train] resumed from {resume_from} at iteration {runner.current_learning_iteration}")
    try:
        runner.learn(int(cfg["max_iterations"]), init_at_random_ep_len=resume_from is None)
        exported = export_policy(runner, run_dir / "exported")
        print(f"[train] run dir {run_dir}; exported {exported}")
    finally:
        env.close()
    return run_dir


if __name__ == "__main__":
    main()
