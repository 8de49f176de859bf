"""Learning curve of a ``base_mpc_cost`` run: the trajectory cost and its terms beside base's reward terms.

``viz.learning_curve`` keeps the run-level columns (return, episode length, KL, std); this adds every
``Episode_Reward/*`` scalar of the run's TensorBoard events (per term: the episode's weighted sum over the episode
length in s, mean over the robots that reset in the iteration; ``mpc_trajectory_cost/<term>`` its split), so the
curve shows what the cost term did. CSV + PNG (return; the trajectory cost by term; velocity tracking).

    python -m experiments.mpc_cost_curve runs/base_mpc_cost/w0.1_s0 \\
        --csv docs/experiments/mpc_cost/learning_curve_w0.1_s0.csv
    python -m experiments.mpc_cost_curve runs/base_mpc_cost/w0.05_s0_cont --append \
        --csv docs/experiments/mpc_cost/learning_curve_w0.05_s0.csv   # a resumed run's later iterations
"""

from __future__ import annotations

import argparse
import csv
import os
from pathlib import Path

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.viz.learning_curve import COLUMNS, read_run

TERM = "mpc_trajectory_cost"


def read_rewards(run_dir: Path) -> list[dict[str, float]]:
    """Rows {iteration, <viz.learning_curve columns>, <every Episode_Reward/* tag without its prefix>}."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    rows = {r["iteration"]: dict(r) for r in read_run(run_dir)}
    for events in sorted(Path(run_dir).glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            if tag.startswith("Episode_Reward/"):
                for ev in acc.Scalars(tag):
                    rows.setdefault(ev.step, {"iteration": ev.step})[tag.removeprefix("Episode_Reward/")] = ev.value
    return [rows[k] for k in sorted(rows)]


def write(rows: list[dict[str, float]], csv_path: Path, png_path: Path | None) -> None:
    """CSV (atomic) and, with ``png_path``, the three panels."""
    reward_cols = sorted({k for r in rows for k in r if k not in COLUMNS and k != "iteration"})
    cols = ["iteration", *[c for c in COLUMNS if any(c in r for r in rows)], *reward_cols]
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = csv_path.with_name(csv_path.name + ".tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([int(r["iteration"])] + [f"{r[c]:.5g}" if c in r else "" for c in cols[1:]])
    os.replace(tmp, csv_path)
    if png_path is None:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [r["iteration"] for r in rows]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    ax[0].plot(it, [r.get("mean_reward", float("nan")) for r in rows], label="return (training reward)")
    ax[0].set_title("return per episode")
    for c in [c for c in reward_cols if c.startswith(TERM)]:
        ax[1].plot(it, [r.get(c, float("nan")) for r in rows], label=c.removeprefix(TERM).lstrip("/") or "total",
                   lw=2.5 if c == TERM else 1.0)
    ax[1].set_title("W c per second of episode, by term")
    ax[1].legend(fontsize=7, ncol=2)
    for c in ("track_lin_vel_xy", "track_ang_vel_z"):
        ax[2].plot(it, [r.get(c, float("nan")) for r in rows], label=c)
    ax[2].set_title("velocity tracking terms per second of episode")
    ax[2].legend(fontsize=7)
    for a in ax:
        a.set_xlabel("iteration")
    fig.tight_layout()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> Path:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--csv", type=Path, required=True)
    p.add_argument("--png", type=Path, default=None, help="default: the CSV's path with .png")
    p.add_argument("--append", action="store_true",
                   help="a resumed run: keep the CSV's rows and add the run's later iterations after them")
    args = p.parse_args(argv)
    try:
        rows = read_rewards(args.run_dir)
    except FileNotFoundError as err:
        raise UserError(str(err)) from None
    if args.append:
        if not args.csv.is_file():
            raise UserError(f"--append: {args.csv} not found")
        with open(args.csv, newline="") as fh:
            kept = [{k: float(v) for k, v in r.items() if v != ""} for r in csv.DictReader(fh)]
        last = max(r["iteration"] for r in kept)
        rows = kept + [r for r in rows if r["iteration"] > last]
    write(rows, args.csv, args.png or args.csv.with_suffix(".png"))
    print(f"{len(rows)} iterations -> {args.csv}")
    return args.csv


if __name__ == "__main__":
    run_cli(main)
