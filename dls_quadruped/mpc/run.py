"""``python -m dls_quadruped.mpc.run``: the model-based baseline walking with a velocity command.

Runs periodic trot + heuristic footholds (eq. 2.2.4) + the force-only sampling MPC at 100 Hz in
the simulator backend (low-level control at 200 Hz) and writes to ``--out``:

* ``summary.json``: mean velocity after the first 2 s, tracking error, falls, solve settings;
* ``baseline.png``: base velocity vs command, Hildebrand gait diagram, initial/rollout cost per step;
* ``walk.gif`` where offscreen rendering works (``MUJOCO_GL=egl`` or ``osmesa``).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported anywhere

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dls_quadruped.mpc.baseline import BaselineConfig, BaselineRun, run_baseline
from dls_quadruped.mpc.config import KERNELS, SamplerConfig
from dls_quadruped.viz.video import render_gif


def plot_baseline(run: BaselineRun, cmd: tuple[float, float, float], path: Path, robot: int = 0) -> None:
    """Velocity tracking, contacts and MPC costs of one robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    t = run.time
    for i, name in enumerate(("v_x", "v_y")):
        axes[0].plot(t, run.base_vel_w[:, robot, i], label=f"{name} (world)")
        axes[0].axhline(cmd[i], ls="--", lw=0.8, color=f"C{i}")
    axes[0].set_ylabel("base velocity [m/s]")
    axes[0].legend(loc="upper right")
    for leg, name in enumerate(("FL", "FR", "RL", "RR")):
        axes[1].fill_between(t, leg + 0.1, leg + 0.9, where=run.contact[:, robot, leg] > 0.5, step="post", color="k")
    axes[1].set_yticks([0.5, 1.5, 2.5, 3.5], ["FL", "FR", "RL", "RR"])
    axes[1].set_ylabel("stance")
    axes[2].semilogy(t, run.best_cost[:, robot], label="rollout cost (chosen sample)")
    axes[2].semilogy(t, np.maximum(run.initial_cost[:, robot], 1e-3), label="initial cost (current state)")
    axes[2].set_ylabel("MPC cost")
    axes[2].set_xlabel("time [s]")
    axes[2].legend(loc="upper right")
    fig.suptitle("model-based baseline: trot + heuristic footholds + sampling MPC on the forces")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vx", type=float, default=0.5, help="forward velocity command [m/s]")
    parser.add_argument("--vy", type=float, default=0.0, help="lateral velocity command [m/s]")
    parser.add_argument("--yaw-rate", type=float, default=0.0, help="yaw-rate command [rad/s]")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--samples", type=int, default=10000, help="M, samples per solve")
    parser.add_argument("--horizon", type=int, default=10, help="N, rollout steps of dt = 0.02 s")
    parser.add_argument("--kernel", choices=KERNELS, default=SamplerConfig.kernel)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-video", action="store_true")
    parser.add_argument("--out", type=Path, default=Path("results/mpc_baseline"))
    args = parser.parse_args()
    if args.seconds <= 0:
        parser.error("--seconds must be > 0")
    cmd = (args.vx, args.vy, args.yaw_rate)
    cfg = BaselineConfig(sampler=SamplerConfig(num_samples=args.samples, horizon=args.horizon, kernel=args.kernel))
    t0 = time.perf_counter()
    run = run_baseline(cmd, args.seconds, cfg=cfg, seed=args.seed, device=args.device)
    wall = time.perf_counter() - t0
    settle = run.time > 2.0
    vel = run.base_vel_w[settle, 0, :2].mean(axis=0)
    summary = {
        "command": cmd, "seconds": args.seconds, "samples": args.samples, "horizon": args.horizon,
        "kernel": args.kernel, "device": args.device, "mean_velocity_xy_after_2s": vel.tolist(),
        "velocity_error_xy": (vel - np.array(cmd[:2])).tolist(), "fallen": bool(run.fallen[0]),
        "median_rollout_cost": float(np.median(run.best_cost[:, 0])),
        "median_initial_cost": float(np.median(run.initial_cost[:, 0])), "wall_seconds": wall,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot_baseline(run, cmd, args.out / "baseline.png")
    print(json.dumps(summary, indent=2))
    print(f"wrote {args.out / 'summary.json'} and {args.out / 'baseline.png'}")
    if not args.no_video:
        print(render_gif(run, args.out / "walk.gif"))


if __name__ == "__main__":
    main()
