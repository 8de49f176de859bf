"""Table 16 and Fig. 29 (thesis 7.3.4): number of samples M in {4 000, 10 000, 25 000}, first-spline,
H = 10, dt = 0.02 s, forces only, simple task; Δ: the change against M = 10 000 on the same episodes,
sum_e (x_e - x_e^10000) / sum_e x_e^10000 over per-episode medians (seed-averaged), with its 95 % interval.

    python -m experiments.table16_samples --scale small

``--seed-students DIR``: the RL rows from three students (training seeds, as ``cost_gap.py``), each with the
sampler seeds, merged per row; e.g. only the headline cells, M = 4 000 and 10 000:

    python -m experiments.table16_samples --scale medium --seed-students runs/students_seeds \
        --out results/experiments/table16_seeds --only rl_warm_start_M4000_seed{0,1,2} \
        rl_warm_start_M10000_seed{0,1,2} naive_warm_start_M4000 naive_warm_start_M10000
"""

from __future__ import annotations

from pathlib import Path

from dls_quadruped.cli import run_cli
from experiments.output import pyplot, save
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_seed_rows, seed_student_cells
from experiments.warm_start_tables import finish, med, paired, survival, tabulate

SAMPLES = (4000, 10000, 25000)
THESIS = {  # (controller, M): (RL reward, initial cost, rollout cost)
    ("rl_warm_start", 4000): (2.348, 33.64, 333.5), ("rl_warm_start", 10000): (2.347, 32.10, 303.3),
    ("rl_warm_start", 25000): (2.348, 30.62, 278.4), ("naive_warm_start", 4000): (2.252, 33.82, 243.4),
    ("naive_warm_start", 10000): (2.261, 28.47, 193.6), ("naive_warm_start", 25000): (2.269, 27.15, 172.6),
}


def cells() -> list[Cell]:
    return [Cell(f"{ctrl}_M{m}", ctrl, {"num_samples": m}, row={"Controller": ctrl, "M": m})
            for ctrl in ("rl_warm_start", "naive_warm_start") for m in SAMPLES]


def figure(results: dict, path: Path) -> None:
    """Fig. 29: initial cost vs M (median, 95 % CI)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for off, ctrl, color in ((-0.03, "rl_warm_start", "C0"), (0.03, "naive_warm_start", "C1")):
        xs, ms, lo, hi = [], [], [], []
        for m in SAMPLES:
            s = results.get(f"{ctrl}_M{m}", {})
            ic = s.get("initial_cost")
            if not ic or not ic.get("n"):
                continue
            a, b = ic.get("ci95", [ic["q1"], ic["q3"]])
            xs.append(m * (1 + off)), ms.append(ic["median"]), lo.append(ic["median"] - a), hi.append(b - ic["median"])
        if xs:
            ax.errorbar(xs, ms, yerr=[lo, hi], fmt="o-", color=color, capsize=3, label=ctrl)
    ax.set_xscale("log")
    ax.set_xlabel("samples M")
    ax.set_ylabel("initial cost (median, 95 % CI)")
    ax.set_title("Fig. 29: initial cost vs number of samples", fontsize=9)
    ax.legend(fontsize=8)
    save(fig, path)


def _flags(p) -> None:
    p.add_argument("--seed-students", type=Path, default=None,
                   help="students as seeds: every RL warm-start cell runs once per training seed k = 0, 1, 2 with "
                        "<dir>/first-spline_H10_dt0.02_seed<k>/exported/student.pt2 and its row merges them "
                        "(default: the one committed student)")


def main() -> None:
    args = parse_args(__doc__, "table16_samples", _flags)
    rows_of = cells()
    todo, seeded = seed_student_cells(rows_of, args.seed_students, args.only) if args.seed_students else (rows_of, {})
    results = run_cells(todo, args)
    merge_seed_rows(results, seeded)

    def columns(c: Cell, s: dict) -> dict:
        ref = f"{c.controller}_M10000"

        def delta(key: str) -> str:
            return "" if c.name == ref else paired(results, c.name, ref, key, relative=True)

        return {"RL reward": med(s["rl_reward"], 3), "Δ reward": delta("rl_reward"),
                "Initial cost": med(s["initial_cost"]), "Δ initial": delta("initial_cost"),
                "Rollout cost (state)": med(s.get("rollout_cost")), "Δ rollout": delta("rollout_cost"),
                "Rollout J (full)": med(s.get("rollout_cost_full")), "Survival": survival(s)}

    def thesis(c: Cell) -> dict:
        th = THESIS.get((c.controller, c.row["M"]), (None, None, None))
        return {"thesis RL reward": th[0] or "-", "thesis initial": th[1] or "-", "thesis rollout": th[2] or "-"}

    cols = ["Controller", "M", "RL reward", "Δ reward", "Initial cost", "Δ initial", "Rollout cost (state)",
            "Δ rollout", "Rollout J (full)", "Survival", "thesis RL reward", "thesis initial", "thesis rollout"]
    students = "; RL rows: 3 students x the sampler seeds" if seeded else ""
    finish(args, todo, results, tabulate(rows_of, results, columns, thesis), cols,
           f"Table 16 (first-spline, H = 10, dt = 0.02 s, F only; Δ vs M = 10 000{students})", figure, "fig29.png")


if __name__ == "__main__":
    run_cli(main)
