"""The RL - naive initial-cost gap of Table 14, taken apart.

Table 14 ran one student per encoding, while Table 15 showed students of one setting differ by up to 1.3x in
initial cost. Here the first-spline and discrete-discrete rows each take **three students** (training seeds,
``--seed-students``: ``<enc>_H10_dt0.02_seed<k>/exported/student.pt2``, made by ``make distill ... --seed k``
at the medium distillation scale), every student with the sampler seeds on the same scheduled episodes as the
naive warm start of its encoding. Per encoding:

* the RL row merges its students (``merge_training_seeds``: intervals over students and episodes);
* paired RL - naive differences of the initial cost as Table 14 reports it (per-episode median) and as a
  per-episode **mean**, and of each of its terms (z,
  vx, vy, vz, roll, pitch, roll, pitch and yaw rates; the terms' means add up to the total's), of the state-only
  rollout cost and of its terms (the chosen sample's reference rollout on every 10th solve,
  ``MPCResult.state_terms``; their means add up to ``rollout_terms_mean``), the reward per step and the **return
  per episode** (the headline where survival differs);
* each student's own RL - naive initial cost, to show how far students of one setting differ.

``--com-height`` scores every controller against one height reference (the MPC's and the probe's): run once
at the default and once at the height the expert walks (0.357 m for the first base expert) to see how much of
the gap is the reference.

    python -m experiments.cost_gap --scale medium --seed-students runs/students_seeds
    python -m experiments.cost_gap --scale medium --seed-students runs/students_seeds --com-height 0.357 \\
        --out results/experiments/cost_gap_h0.357
"""

from __future__ import annotations

from pathlib import Path

from dls_quadruped.cli import run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.mpc.cost import STATE_TERMS
from experiments.output import pyplot, save, write_table
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import (
    SEED_STUDENTS,
    merge_seed_rows,
    seed_student_cells,
)
from experiments.warm_start_tables import finish, med, paired, survival

ENCODINGS = (("first", "spline"), ("discrete", "discrete"))
SEEDS = SEED_STUDENTS


def cells(students: Path, only: list[str] | None = None) -> tuple[list[Cell], dict[str, list[str]]]:
    """(cells to run, {merged RL row: its students' cells}); the students of the cells selected (``only``: those
    named, None: all) must exist."""
    base = []
    for p, F in ENCODINGS:
        sampler = {"encoding_p": p, "encoding_F": F}
        base += [Cell(f"rl_warm_start_{p}-{F}", "rl_warm_start", sampler,
                      row={"Controller": "rl_warm_start", "p": p, "F": F}),
                 Cell(f"naive_warm_start_{p}-{F}", "naive_warm_start", sampler,
                      row={"Controller": "naive_warm_start", "p": p, "F": F})]
    return seed_student_cells(base, students, only, SEEDS)


def gap_rows(results: dict, rows: dict[str, list[str]]) -> list[dict]:
    """One row per encoding and quantity: RL (students merged) - naive, paired on the same episodes."""
    out = []
    for p, F in ENCODINGS:
        enc = f"{p}-{F}"
        rl, naive = f"rl_warm_start_{enc}", f"naive_warm_start_{enc}"
        if rl not in results or naive not in results or "skipped" in results[rl] or "skipped" in results[naive]:
            continue
        quantities = [("initial cost (median per episode, Table 14's)", "initial_cost", 1),
                      ("initial cost (mean per episode)", "initial_cost_mean", 1)]
        quantities += [(f"  term {t}", f"initial_term_{t}", 2) for t in STATE_TERMS]
        quantities += [("rollout cost, state (median per episode)", "rollout_cost", 1),
                       ("rollout cost, state (mean per episode, recorded solves)", "rollout_terms_mean", 1)]
        quantities += [(f"  rollout term {t}", f"rollout_term_{t}", 1) for t in STATE_TERMS]
        quantities += [("reward per step", "rl_reward", 3), ("return per episode", "rl_return", 1),
                        ("survived", "survived", 2)]
        for label, key, digits in quantities:
            row = {"p, F": f"{p}, {F}", "quantity": label,
                   "RL - naive (3 students)": paired(results, rl, naive, key, digits),
                   "median of the episodes' differences": paired(results, rl, naive, key, digits, median=True)}
            for k, name in enumerate(rows[rl]):
                row[f"student {k} - naive"] = paired(results, name, naive, key, digits)
            out.append(row)
    return out


def cell_rows(todo: list[Cell], results: dict, rows: dict[str, list[str]]) -> list[dict]:
    out = []
    for name in [*rows, *(c.name for c in todo)]:
        s = results.get(name)
        if not s:
            continue
        label = {"Controller": "rl_warm_start, 3 students merged", "cell": name} if name in rows else \
            {"Controller": next(c.row["Controller"] for c in todo if c.name == name), "cell": name}
        if "skipped" in s:
            out.append({**label, "RL reward": f"skipped: {s['skipped']}"})
            continue
        out.append({**label, "RL reward": med(s["rl_reward"], 3), "RL return": med(s.get("rl_return"), 0),
                    "Initial cost": med(s["initial_cost"]), "Rollout cost (state)": med(s.get("rollout_cost")),
                    "Survival": survival(s)})
    return out


def figure(results: dict, path: Path) -> None:
    """Per encoding: the RL - naive difference of each initial-cost term and each state rollout-cost term (the
    median over episodes of the paired differences, 95 % interval: a robot that stumbled in one episode swamps
    the mean); the rollout panel only where the cells recorded the rollout terms."""
    import numpy as np

    from dls_quadruped.eval.metrics import paired_difference

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(14, 4))
    terms = list(STATE_TERMS)
    for ax, prefix, what in ((axes[0], "initial_term_", "initial cost"),
                             (axes[1], "rollout_term_", "state rollout cost")):
        for j, (p, F) in enumerate(ENCODINGS):
            rl, naive = results.get(f"rl_warm_start_{p}-{F}", {}), results.get(f"naive_warm_start_{p}-{F}", {})
            if "per_episode" not in rl or "per_episode" not in naive:
                continue
            for i, t in enumerate(terms):
                key = prefix + t
                if key not in rl["per_episode"] or key not in naive["per_episode"]:
                    continue
                d = paired_difference(np.array(rl["per_episode"][key]), np.array(naive["per_episode"][key]))
                m, (lo, hi) = d["median"], d["median_ci95"]
                ax.errorbar(i + 0.2 * (j - 0.5), m, yerr=[[m - lo], [hi - m]],
                            fmt="o", color=f"C{j}", capsize=3, label=f"{p}-{F}" if i == 0 else None)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(range(len(terms)), terms, rotation=30)
        ax.set_ylabel(f"RL - naive, {what} term\n(median of the episodes' paired differences)", fontsize=8)
        ax.set_title(f"{what.capitalize()} gap by term (3 students x sampler seeds, paired episodes)", fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    save(fig, path)


def _flags(p) -> None:
    p.add_argument("--seed-students", type=Path, required=True,
                   help="folder of <p>-<F>_H10_dt0.02_seed<k>/exported/student.pt2, k = 0, 1, 2")


def main() -> None:
    args = parse_args(__doc__, "cost_gap", _flags)
    todo, rows = cells(args.seed_students, args.only)
    results = run_cells(todo, args)
    merge_seed_rows(results, rows)
    write_gap = gap_rows(results, rows)
    gap_cols = ["p, F", "quantity", "RL - naive (3 students)", "median of the episodes' differences",
                *(f"student {k} - naive" for k in range(SEEDS))]
    write_table(write_gap, gap_cols, args.out / "gap", "RL - naive warm start, paired on the same episodes "
                f"(mean [95 % CI]; height reference {args.com_height or 'default'})")
    write_json({"gap": write_gap, **provenance()}, args.out / "gap.json", indent=1)
    cols = ["Controller", "cell", "RL reward", "RL return", "Initial cost", "Rollout cost (state)", "Survival"]
    finish(args, todo, results, cell_rows(todo, results, rows), cols,
           "Table 14's first-spline and discrete-discrete rows, 3 students each (M = 10 000, H = 10, dt = 0.02 s, "
           "F only)", figure, "cost_gap.png")
    print((args.out / "gap.md").read_text())


if __name__ == "__main__":
    run_cli(main)
