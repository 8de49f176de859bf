"""``make demo``: N AlienGo robots stand, then trot in place, driven by the balance controller.

Writes to ``--out`` (default ``results/demo``):

* ``summary.json``: the foundation's pass/fail numbers (height error, roll, pitch, foot lift, falls);
* ``balance.png``: base height, roll/pitch and a Hildebrand-style gait diagram of robot 0;
* ``trot.gif``: robot 0 rendered offscreen (MuJoCo renderer; set ``MUJOCO_GL=egl`` or ``osmesa``),
  or a message saying why no video was written.
"""

from __future__ import annotations

import os

# the GL backend is chosen when mujoco is first imported: headless EGL unless the user chose one
os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path

import numpy as np

from dls_quadruped.cli import (
    ArgumentParser,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
)
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.balance_run import BalanceRun, run_balance
from dls_quadruped.viz.video import render_gif


def plot_run(run: BalanceRun, path: Path, robot: int = 0) -> None:
    """Base height, attitude and gait diagram of one robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    t = run.time
    axes[0].plot(t, run.base_height[:, robot])
    axes[0].set_ylabel("base height [m]")
    axes[1].plot(t, run.roll[:, robot], label="roll")
    axes[1].plot(t, run.pitch[:, robot], label="pitch")
    axes[1].set_ylabel("[rad]")
    axes[1].legend(loc="upper right")
    contact = run.contact_cmd[:, robot]
    for leg, name in enumerate(("FL", "FR", "RL", "RR")):
        axes[2].fill_between(t, leg + 0.1, leg + 0.9, where=contact[:, leg] > 0.5, step="post", color="k")
    axes[2].set_yticks([0.5, 1.5, 2.5, 3.5], ["FL", "FR", "RL", "RR"])
    axes[2].set_ylabel("stance")
    axes[2].set_xlabel("time [s]")
    start = t[np.argmax(run.trotting)] if run.trotting.any() else None
    for ax in axes:
        if start is not None:
            ax.axvline(start, color="gray", ls="--", lw=0.8)
    fig.suptitle("balance-controller baseline: stand, then trot in place (dashed: trot starts)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description="Stand then trot in place with the balance-controller baseline.")
    parser.add_argument("--num-envs", type=positive_int, default=64)
    parser.add_argument("--seconds", type=positive_float, default=5.0, help="duration of each phase (stand, trot) [s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=non_negative_int, default=0, help="backend worker processes (0: in-process)")
    parser.add_argument("--out", type=Path, default=Path("results/demo"))
    args = parser.parse_args(argv)
    run = run_balance(num_envs=args.num_envs, stand_seconds=args.seconds, trot_seconds=args.seconds, seed=args.seed,
                      num_workers=args.workers)
    args.out.mkdir(parents=True, exist_ok=True)
    text = write_json(run.summary, args.out / "summary.json")
    plot_run(run, args.out / "balance.png")
    print(text)
    print(f"wrote {args.out / 'summary.json'} and {args.out / 'balance.png'}")
    print(render_gif(run, args.out / "trot.gif"))
    return run.summary


if __name__ == "__main__":
    run_cli(main)
