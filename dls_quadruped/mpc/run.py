"""``python -m dls_quadruped.mpc.run``: the model-based baseline walking with a velocity command.

Runs periodic trot + heuristic footholds (eq. 2.2.4) + the force-only sampling MPC at 100 Hz in
an env of the home task (``closed_loop/baseline_run.py``; low-level control at 200 Hz) and writes to ``--out``:

* ``summary.json``: mean velocity after the first 2 s, tracking error, falls, solve settings;
* ``baseline.png``: base velocity vs command, Hildebrand gait diagram, initial/rollout cost per step;
* ``walk.gif`` where offscreen rendering works (``MUJOCO_GL=egl`` or ``osmesa``).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported anywhere

import time
from pathlib import Path

import numpy as np

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    finite_float,
    positive_float,
    positive_int,
    run_cli,
    torch_device,
)
from dls_quadruped.closed_loop.baseline_run import BaselineRun, run_baseline
from dls_quadruped.core.json_io import write_json
from dls_quadruped.mpc.baseline import BaselineConfig
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


SETTLE_S = 2.0
"""Velocity statistics start after this much time [s] (the gait starts from standing)."""


def summarize(run: BaselineRun, cmd: tuple[float, float, float], settle_s: float = SETTLE_S) -> dict:
    """Mean planar velocity after ``settle_s`` and its error; over the whole run when it is shorter
    (``velocity_window_s`` says which), so a short run never averages an empty window into NaN."""
    window = run.time > settle_s
    if not window.any():
        window = np.ones_like(run.time, dtype=bool)
    vel = run.base_vel_w[window, 0, :2].mean(axis=0)
    return {
        "velocity_window_s": [float(run.time[window][0]), float(run.time[window][-1])],
        "mean_velocity_xy": vel.tolist(), "velocity_error_xy": (vel - np.array(cmd[:2])).tolist(),
        "fallen": bool(run.fallen[0]),
        "median_rollout_cost": float(np.median(run.best_cost[:, 0])),
        "median_initial_cost": float(np.median(run.initial_cost[:, 0])),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vx", type=finite_float, default=0.5, help="forward velocity command [m/s]")
    parser.add_argument("--vy", type=finite_float, default=0.0, help="lateral velocity command [m/s]")
    parser.add_argument("--yaw-rate", type=finite_float, default=0.0, help="yaw-rate command [rad/s]")
    parser.add_argument("--seconds", type=positive_float, default=15.0)
    parser.add_argument("--samples", type=positive_int, default=10000, help="M, samples per solve")
    parser.add_argument("--horizon", type=positive_int, default=10, help="N, rollout steps of dt = 0.02 s")
    parser.add_argument("--kernel", choices=KERNELS, default=SamplerConfig.kernel)
    parser.add_argument("--anchor-share", type=finite_float, default=0.0,
                        help="share of the samples drawn around the nominal trot besides the naive warm start "
                             "(default 0: naive warm start alone, the thesis's naive controller)")
    parser.add_argument("--device", type=torch_device, default="cpu", help="cpu, cuda or cuda:<index>")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-video", action="store_true")
    parser.add_argument("--out", type=Path, default=Path("results/mpc_baseline"))
    args = parser.parse_args(argv)
    cmd = (args.vx, args.vy, args.yaw_rate)
    try:
        cfg = BaselineConfig(anchor_share=args.anchor_share,
                             sampler=SamplerConfig(num_samples=args.samples, horizon=args.horizon, kernel=args.kernel))
    except ValueError as err:
        raise UserError(str(err)) from None
    if args.seconds < cfg.sampler.mpc_period:
        raise UserError(f"--seconds must cover at least one MPC period ({cfg.sampler.mpc_period} s), "
                        f"got {args.seconds}")
    t0 = time.perf_counter()
    run = run_baseline(cmd, args.seconds, cfg=cfg, seed=args.seed, device=args.device)
    wall = time.perf_counter() - t0
    summary = {"command": cmd, "seconds": args.seconds, "samples": args.samples, "horizon": args.horizon,
               "kernel": args.kernel, "device": args.device, "anchor_share": args.anchor_share,
               **summarize(run, cmd), "wall_seconds": wall}
    args.out.mkdir(parents=True, exist_ok=True)
    text = write_json(summary, args.out / "summary.json")
    plot_baseline(run, cmd, args.out / "baseline.png")
    print(text)
    print(f"wrote {args.out / 'summary.json'} and {args.out / 'baseline.png'}")
    if not args.no_video:
        print(render_gif(run, args.out / "walk.gif"))
    return summary


if __name__ == "__main__":
    run_cli(main)
