"""Learning curve of a training run from its TensorBoard events: CSV + PNG.

    python -m dls_quadruped.viz.learning_curve runs/base/<run> --csv docs/learning_curve_base.csv \
        --png docs/learning_curve_base.png

Per PPO iteration: ``Train/mean_reward`` (mean return of the episodes finished so far, rsl-rl's
window of 100), ``Train/mean_episode_length`` [policy steps, 50 per s], the velocity-tracking error
``Episode_Metric/lin_vel_xy_error`` (|v_xy,b - v_cmd,xy| averaged over each finished episode [m/s],
logged by ``LocomotionEnv``), the iteration time (``Perf/collection_time + Perf/learning_time`` [s]),
the mean exploration std of the actions (``Policy/mean_std``) and, where the task has them, the
terrain-level and forward-speed curricula (``Curriculum/terrain_levels``, ``Curriculum/speed``), then
the training diagnostics (``learning/diagnostics.py``, docs/train.md "Diagnostics"): the learning rate, the KL
per update, the action std, clip and |a| > 1 fractions per latent-action group (f, d, p, F) and the fractions
of (step, leg) in which F and p were ignored. After those fixed columns come, named as their tags and sorted, every
scalar under ``EXTRA_PREFIXES`` the run logged: PPO's losses (``Loss/value``, ``Loss/surrogate``, ...), each
reward term's episode sum per second (``Episode_Reward/<term>``) and each termination's count
(``Episode_Termination/<term>``), so a return that collapses can be traced to a term and a loss from the CSV alone.
A run that lacks a scalar (older runs: every diagnostic) leaves its cells empty; fixed columns are only ever appended,
so older CSVs read the same way.

``--trend LAST [BLOCK]`` also answers "is the return still rising?" (:func:`trend`): the mean return in
BLOCK-iteration blocks (default 50) over the last LAST iterations, a least-squares line through the block means and
its slope's 95 % interval (Student's t, blocks - 2 degrees of freedom): **rising** if the interval lies above 0,
**falling** if below, else **flat**. The blocks are autocorrelated, so the interval is, if anything, too narrow.
"""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.control.latent_action import ACTION_GROUPS
from dls_quadruped.core.stats import t_quantile

COLUMNS = {
    "mean_reward": "Train/mean_reward",
    "mean_episode_length": "Train/mean_episode_length",
    "lin_vel_xy_error": "Episode_Metric/lin_vel_xy_error",
    "collection_s": "Perf/collection_time",
    "learning_s": "Perf/learning_time",
    "action_std": "Policy/mean_std",
    "terrain_level": "Curriculum/terrain_levels",
    "speed_range": "Curriculum/speed",
    "learning_rate": "Loss/learning_rate",
    "kl_mean": "Diagnostics/kl_mean",
    "kl_max": "Diagnostics/kl_max",
    **{f"std_{g}": f"Diagnostics/std_{g}" for g, _ in ACTION_GROUPS},
    "clip_frac": "Diagnostics/clip_frac",
    **{f"clip_frac_{g}": f"Diagnostics/clip_frac_{g}" for g, _ in ACTION_GROUPS},
    **{f"outside_unit_frac_{g}": f"Diagnostics/outside_unit_frac_{g}" for g, _ in ACTION_GROUPS},
    "F_ignored_frac": "Diagnostics/F_ignored_frac",
    "p_ignored_frac": "Diagnostics/p_ignored_frac",
}
EXTRA_PREFIXES = ("Loss/", "Episode_Reward/", "Episode_Termination/")
"""Tags kept as their own columns after ``COLUMNS`` (those ``COLUMNS`` already names are not repeated)."""


def read_run(run_dir: Path) -> list[dict[str, float]]:
    """Rows {iteration, <COLUMNS>, <extra tags>} from every event file of ``run_dir`` (later files win on resume)."""
    rows: dict[int, dict[str, float]] = {}
    for events in sorted(Path(run_dir).glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        tags = set(acc.Tags()["scalars"])
        named = set(COLUMNS.values())
        extra = {t: t for t in tags if t.startswith(EXTRA_PREFIXES) and t not in named}
        for col, tag in {**COLUMNS, **extra}.items():
            if tag in tags:
                for ev in acc.Scalars(tag):
                    rows.setdefault(ev.step, {"iteration": ev.step})[col] = ev.value
    if not rows:
        raise FileNotFoundError(f"no TensorBoard scalars under {run_dir}")
    return [rows[k] for k in sorted(rows)]


def write_csv(rows: list[dict[str, float]], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = sorted({c for r in rows for c in r} - set(COLUMNS) - {"iteration"})
    cols = ["iteration", *COLUMNS, *extra]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([r["iteration"]] + [f"{r[c]:.5g}" if c in r else "" for c in cols[1:]])


def plot(rows: list[dict[str, float]], path: Path, title: str, marks: tuple[int, ...] = ()) -> None:
    """Four panels over the iterations; ``marks``: iterations to draw as dotted lines (e.g. a resume, the
    exported checkpoint)."""
    it = [r["iteration"] for r in rows]
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.6))
    specs = [("mean_reward", "mean reward (episode return)"), ("mean_episode_length", "mean episode length [steps]"),
             ("lin_vel_xy_error", "velocity-tracking error |v_xy - v_cmd| [m/s]"),
             ("action_std", "mean action std (exploration)")]
    for ax, (col, label) in zip(axes, specs):
        pts = [(i, r[col]) for i, r in zip(it, rows) if col in r]
        if pts:
            ax.plot(*zip(*pts), lw=1.2)
        ax.set_xlabel("PPO iteration")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
        for m in marks:
            ax.axvline(m, color="tab:red", ls=":", lw=1.0)
    axes[1].axhline(750, color="grey", ls="--", lw=0.8, label="15 s episode (time-out)")
    axes[2].axhline(0.15, color="grey", ls="--", lw=0.8, label="0.15 m/s (target on the simple task)")
    for ax in axes[1:3]:
        ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def check_window(last: int, block: int = 50) -> None:
    """Raise ValueError unless ``last`` is a positive multiple of ``block`` with at least three blocks."""
    if block < 1 or last % block or last // block < 3:
        raise ValueError(f"last ({last}) must be a multiple of block ({block}) with at least 3 blocks")


def trend(rows: list[dict[str, float]], last: int, block: int = 50, column: str = "mean_reward") -> dict:
    """Slope of ``column`` over the last ``last`` iterations of ``rows``: block means of ``block`` consecutive
    iterations (``last`` must be a multiple of it, at least three blocks), a least-squares line through them
    (x: the block's mean iteration), the slope [per iteration] and per 100 iterations with the 95 % interval
    (Student's t, blocks - 2 degrees of freedom), and the reading: ``rising``, ``falling`` or ``flat``."""
    check_window(last, block)
    pts = [(r["iteration"], r[column]) for r in rows if column in r][-last:]
    if len(pts) < last:
        raise ValueError(f"the run has {len(pts)} iterations with {column}, the trend asks for the last {last}")
    its = np.array([p[0] for p in pts], dtype=float).reshape(-1, block).mean(axis=1)
    means = np.array([p[1] for p in pts], dtype=float).reshape(-1, block).mean(axis=1)
    n = len(means)
    xc = its - its.mean()
    slope = float(xc @ (means - means.mean()) / (xc @ xc))
    resid = means - means.mean() - slope * xc
    se = float(np.sqrt(resid @ resid / (n - 2) / (xc @ xc)))
    half = t_quantile(0.975, n - 2) * se
    lo, hi = slope - half, slope + half
    reading = "rising" if lo > 0 else "falling" if hi < 0 else "flat"
    return {"column": column, "first_iteration": int(pts[0][0]), "last_iteration": int(pts[-1][0]), "block": block,
            "block_means": [float(m) for m in means], "slope_per_100": 100 * slope,
            "ci95_per_100": [100 * lo, 100 * hi], "reading": reading}


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path)
    p.add_argument("--csv", type=Path, required=True)
    p.add_argument("--png", type=Path, required=True)
    p.add_argument("--title", default=None)
    p.add_argument("--mark", type=int, nargs="*", default=[], help="iterations to mark (dotted), e.g. a resume")
    p.add_argument("--trend", type=int, nargs="+", metavar=("LAST", "BLOCK"), default=None,
                   help="also print the mean return's slope over the last LAST iterations in BLOCK-iteration blocks "
                        "(default 50) with its 95 %% interval: rising, flat or falling")
    args = p.parse_args(argv)
    if args.trend is not None:
        if len(args.trend) > 2:
            raise UserError(f"--trend takes LAST and optionally BLOCK, got {args.trend}")
        try:
            check_window(*args.trend)  # before anything is read or written
        except ValueError as e:
            raise UserError(f"--trend: {e}") from None
    rows = read_run(args.run_dir)
    write_csv(rows, args.csv)
    plot(rows, args.png, args.title or f"{args.run_dir}", tuple(args.mark))
    print(f"[learning_curve] {len(rows)} iterations -> {args.csv}, {args.png}")
    if args.trend is not None:
        try:
            t = trend(rows, *args.trend)
        except ValueError as e:
            raise UserError(f"--trend: {e}") from None
        print(f"[learning_curve] {t['column']} over iterations {t['first_iteration']}-{t['last_iteration']} "
              f"({len(t['block_means'])} blocks of {t['block']}): slope {t['slope_per_100']:+.3f} per 100 iterations "
              f"[{t['ci95_per_100'][0]:+.3f}, {t['ci95_per_100'][1]:+.3f}] -> {t['reading']}")


if __name__ == "__main__":
    run_cli(main)  # a bad flag, a missing run directory: one line, exit 2
