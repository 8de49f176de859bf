"""Table 14 and Figs. 26-27 (thesis 7.3.2): RL warm start vs naive warm start vs RL baseline for the six
(p, F) encodings, H = 10, dt = 0.02 s, M = 10 000, the MPC optimising the forces only, simple task.
Δ columns: the RL warm start minus the naive warm start of the same encoding on the same episodes
(mean over episodes of the per-episode difference, 95 % interval over episodes and sampler seeds).

    python -m experiments.table14_warm_start_encodings --scale small

``--seed-students DIR``: every RL warm-start cell runs once per training seed's student
(``<dir>/<p>-<F>_H10_dt0.02_seed<k>/exported/student.pt2``, k = 0, 1, 2) and its row merges them (intervals over
students and episodes, ``experiments/warm_start_seeds.py``); e.g. the first-spline rows at the thesis's scale:

    python -m experiments.table14_warm_start_encodings --scale thesis --seed 1 --sampler-seeds 1 \
        --seed-students docs/policies/seed_students --out results/experiments/table14_thesis \
        --only rl_warm_start_first-spline_seed{0,1,2} naive_warm_start_first-spline rl_baseline
"""

from __future__ import annotations

from pathlib import Path

from dls_quadruped.cli import run_cli
from experiments.output import pyplot, save
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_seed_rows, seed_student_cells
from experiments.warm_start_tables import finish, med, paired, survival, tabulate

ENCODINGS = [("discrete", "discrete"), ("discrete", "spline"), ("spline", "discrete"), ("spline", "spline"),
             ("first", "discrete"), ("first", "spline")]
THESIS = {  # (controller, p, F): (RL reward, initial cost, rollout cost), Table 14 medians
    ("rl_warm_start", "discrete", "discrete"): (2.320, 61.44, 787.3),
    ("rl_warm_start", "discrete", "spline"): (2.336, 46.28, 485.0),
    ("rl_warm_start", "spline", "discrete"): (2.325, 47.56, 581.9),
    ("rl_warm_start", "spline", "spline"): (2.333, 45.72, 455.6),
    ("rl_warm_start", "first", "discrete"): (2.339, 35.15, 432.8),
    ("rl_warm_start", "first", "spline"): (2.347, 30.72, 291.8),
    ("naive_warm_start", "discrete", "discrete"): (1.297, 879.7, 2919),
    ("naive_warm_start", "discrete", "spline"): (2.259, 33.26, 221.5),
    ("naive_warm_start", "spline", "discrete"): (1.331, 854.9, 8107),
    ("naive_warm_start", "spline", "spline"): (2.266, 32.46, 218.4),
    ("naive_warm_start", "first", "discrete"): (1.242, 983.7, 9576),
    ("naive_warm_start", "first", "spline"): (2.259, 31.43, 211.7),
    ("rl_baseline", "-", "-"): (2.365, 86.45, None),
}


def cells() -> list[Cell]:
    out = []
    for ctrl in ("rl_warm_start", "naive_warm_start"):
        for p, F in ENCODINGS:
            out.append(Cell(f"{ctrl}_{p}-{F}", ctrl, {"encoding_p": p, "encoding_F": F},
                            row={"Controller": ctrl, "p": p, "F": F}))
    out.append(Cell("rl_baseline", "rl_baseline", row={"Controller": "rl_baseline", "p": "-", "F": "-"}))
    # beyond the thesis: Algorithm 2's set {previous solution, RL}: half the samples around each
    out.append(Cell("rl_plus_naive_first-spline", "rl_warm_start", {"encoding_p": "first", "encoding_F": "spline"},
                    naive_share=0.5, row={"Controller": "rl_warm_start + naive (50/50)", "p": "first", "F": "spline"}))
    return out


def figure(results: dict, path: Path) -> None:
    """Figs. 26-27: initial cost and state-only rollout cost per encoding, medians with 95 % interval bars."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{p}-{F}" for p, F in ENCODINGS]
    for ax, key, title in ((axes[0], "initial_cost", "Fig. 26: initial (state) cost"),
                           (axes[1], "rollout_cost", "Fig. 27: rollout cost (state-only)")):
        for off, ctrl, color in ((-0.2, "rl_warm_start", "C0"), (0.2, "naive_warm_start", "C1")):
            label = ctrl  # on the controller's first plotted encoding, whichever it is
            for i, (p, F) in enumerate(ENCODINGS):
                s = results.get(f"{ctrl}_{p}-{F}", {})
                m = s.get(key)
                if not m or m.get("n", 0) == 0:
                    continue
                lo, hi = m.get("ci95", [m["q1"], m["q3"]])
                ax.errorbar(i + off, m["median"], yerr=[[m["median"] - lo], [hi - m["median"]]], fmt="o",
                            color=color, capsize=3, label=label)
                label = None
        ax.set_xticks(range(len(labels)), labels, rotation=30)
        ax.set_yscale("log")
        ax.set_title(title + " (median, 95 % CI)", fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    save(fig, path)


def columns_with(results: dict):
    """The table's columns of a cell; an RL warm start's paired differences are against the naive warm
    start with the same encoding (same episodes), the mixed row's against the pure RL warm start."""

    def columns(c: Cell, s: dict) -> dict:
        won = s.get("warm_start_won") or {}
        ref = None
        if c.controller == "rl_warm_start":
            ref = "rl_warm_start_first-spline" if c.naive_share else f"naive_warm_start_{c.row['p']}-{c.row['F']}"
        return {"RL reward": med(s["rl_reward"], 3), "Initial cost": med(s["initial_cost"]),
                "Rollout cost (state)": med(s.get("rollout_cost")), "Rollout J (full)": med(s.get("rollout_cost_full")),
                "Survival": survival(s), "|v_xy - cmd|": med(s["vel_error"], 3),
                "Δ initial (paired)": paired(results, c.name, ref, "initial_cost") if ref else "",
                "Δ rollout state (paired)": paired(results, c.name, ref, "rollout_cost") if ref else "",
                "Δ reward (paired)": paired(results, c.name, ref, "rl_reward", 3) if ref else "",
                "student won": f"{100 * won.get('0', 0.0):.0f} %" if c.naive_share else ""}

    return columns


def thesis(c: Cell) -> dict:
    th = (None, None, None) if c.naive_share else THESIS.get((c.controller, c.row["p"], c.row["F"]), (None, None, None))
    return {"thesis RL reward": th[0] or "-", "thesis initial": th[1] or "-", "thesis rollout": th[2] or "-"}


def _flags(p) -> None:
    p.add_argument("--seed-students", type=Path, default=None,
                   help="students as seeds: every RL warm-start cell runs once per training seed k = 0, 1, 2 with "
                        "<dir>/<p>-<F>_H10_dt0.02_seed<k>/exported/student.pt2 and its row merges them "
                        "(default: one student per encoding, from --students)")


def main() -> None:
    args = parse_args(__doc__, "table14_warm_start", _flags)
    rows_of = cells()
    todo, seeded = seed_student_cells(rows_of, args.seed_students, args.only) if args.seed_students else (rows_of, {})
    results = run_cells(todo, args)
    merge_seed_rows(results, seeded)
    cols = ["Controller", "p", "F", "RL reward", "Initial cost", "Rollout cost (state)", "Rollout J (full)", "Survival",
            "|v_xy - cmd|", "Δ initial (paired)", "Δ rollout state (paired)", "Δ reward (paired)", "student won",
            "thesis RL reward", "thesis initial", "thesis rollout"]
    students = "; RL rows: 3 students x the sampler seeds" if seeded else ""
    finish(args, todo, results, tabulate(rows_of, results, columns_with(results), thesis), cols,
           f"Table 14 (M = 10 000, H = 10, dt = 0.02 s, F only{students})", figure, "fig26_27.png")


if __name__ == "__main__":
    run_cli(main)
