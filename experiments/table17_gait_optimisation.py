"""Table 17 and Fig. 30 (thesis 7.3.5): gait optimisation (none, frequency, duty cycle, full) for the RL
and naive warm starts at forward speeds 0.1, 0.5 and 1.5 m/s (v_y = omega_z = 0, flat), first-spline,
H = 10, dt = 0.02 s, M = 10 000; RL reward, initial cost and survival; the RL baseline beside them.

    python -m experiments.table17_gait_optimisation --scale small

``--seed-students DIR``: the RL warm-start rows from three students (training seeds, as ``cost_gap.py``), each with
the sampler seeds, merged per row; e.g. only the 1.5 m/s headline cells:

    python -m experiments.table17_gait_optimisation --scale medium --seed-students runs/students_seeds \
        --out results/experiments/table17_seeds --only rl_warm_start_no_v1.5_seed{0,1,2} \
        rl_warm_start_full_v1.5_seed{0,1,2} rl_baseline_v1.5
"""

from __future__ import annotations

from pathlib import Path

from dls_quadruped.cli import run_cli
from experiments.output import pyplot, save
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_seed_rows, seed_student_cells
from experiments.warm_start_tables import finish, med, survival

SPEEDS = (0.1, 0.5, 1.5)
GAIT = {"no": ("F",), "frequency": ("F", "f"), "duty": ("F", "d"), "full": ("F", "f", "d")}
THESIS = {  # (controller, gait): RLR, IC, survival [%] at 0.1, 0.5, 1.5 m/s
    ("rl_warm_start", "no"): ((2.175, 2.348, 1.776), (18.65, 26.65, 210.2), (100, 100, 0)),
    ("rl_warm_start", "frequency"): ((2.177, 2.347, 1.781), (22.78, 26.37, 165.9), (100, 100, 0)),
    ("rl_warm_start", "duty"): ((2.063, 2.219, 1.794), (28.74, 39.20, 200.7), (100, 100, 22.6)),
    ("rl_warm_start", "full"): ((2.074, 2.220, 1.688), (27.78, 38.31, 187.8), (100, 100, 14.9)),
    ("naive_warm_start", "no"): ((1.986, 2.280, 1.697), (19.60, 25.17, 219.1), (100, 100, 84.2)),
    ("naive_warm_start", "frequency"): ((1.304, 1.706, 1.695), (28.88, 36.20, 194.9), (5.1, 15.8, 35.1)),
    ("naive_warm_start", "duty"): ((1.173, 1.603, 1.595), (34.47, 24.32, 61.25), (5.0, 0, 0)),
    ("naive_warm_start", "full"): ((1.318, 1.574, 1.601), (21.29, 24.28, 50.69), (7.2, 0, 0)),
    ("rl_baseline", "-"): ((2.217, 2.359, 2.291), (117.7, 76.25, 60.04), (100, 100, 99.8)),
}


def cell_name(ctrl: str, gait: str, v: float) -> str:
    return f"rl_baseline_v{v:g}" if ctrl == "rl_baseline" else f"{ctrl}_{gait}_v{v:g}"


def cells() -> list[Cell]:
    out = []
    for ctrl in ("rl_warm_start", "naive_warm_start"):
        for gait, opt in GAIT.items():
            for v in SPEEDS:
                out.append(Cell(cell_name(ctrl, gait, v), ctrl, optimise=opt, vx=v,
                                row={"Controller": ctrl, "Gait opt.": gait}))
    out += [Cell(cell_name("rl_baseline", "-", v), "rl_baseline", vx=v,
                 row={"Controller": "rl_baseline", "Gait opt.": "-"}) for v in SPEEDS]
    return out


def figure(results: dict, path: Path) -> None:
    """Fig. 30: survival and initial cost vs speed per controller and gait optimisation."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    keys = [(c, g) for c in ("rl_warm_start", "naive_warm_start") for g in GAIT] + [("rl_baseline", "-")]
    for i, (ctrl, gait) in enumerate(keys):
        names = [cell_name(ctrl, gait, v) for v in SPEEDS]
        sv = [results.get(n, {}).get("survival", {}).get("rate") for n in names]
        ic = [(results.get(n, {}).get("initial_cost") or {}).get("median") for n in names]
        style = "-" if ctrl == "rl_warm_start" else "--" if ctrl == "naive_warm_start" else ":"
        label = f"{ctrl} {gait}"
        axes[0].plot(SPEEDS, [100 * s if s is not None else None for s in sv], "o" + style, color=f"C{i % 10}",
                     label=label)
        axes[1].plot(SPEEDS, ic, "o" + style, color=f"C{i % 10}", label=label)
    axes[0].set_ylabel("survival [%]")
    axes[1].set_ylabel("initial cost (median)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("forward speed [m/s]")
    axes[0].legend(fontsize=6)
    axes[0].set_title("Fig. 30: gait optimisation vs speed", fontsize=9)
    save(fig, path)


def _flags(p) -> None:
    p.add_argument("--seed-students", type=Path, default=None,
                   help="students as seeds: every RL warm-start cell runs once per training seed k = 0, 1, 2 with "
                        "<dir>/first-spline_H10_dt0.02_seed<k>/exported/student.pt2 and its row merges them "
                        "(default: the one committed student)")


def main() -> None:
    args = parse_args(__doc__, "table17_gait_optimisation", _flags)
    todo, seeded = seed_student_cells(cells(), args.seed_students, args.only) if args.seed_students else (cells(), {})
    results = run_cells(todo, args)
    merge_seed_rows(results, seeded)
    rows = []
    for ctrl, gait in [(c, g) for c in ("rl_warm_start", "naive_warm_start") for g in GAIT] + [("rl_baseline", "-")]:
        row = {"Controller": ctrl, "Gait opt.": gait}
        th = THESIS[(ctrl, gait)]
        for i, v in enumerate(SPEEDS):
            s = results.get(cell_name(ctrl, gait, v))
            if s is None or "skipped" in s:
                row[f"RLR {v:g}"] = "skipped" if s else "-"
                continue
            row[f"RLR {v:g}"] = f"{s['rl_reward']['median']:.3f} ({th[0][i]})"
            row[f"IC {v:g}"] = f"{med(s['initial_cost'])} ({th[1][i]})"
            row[f"Surv {v:g}"] = f"{survival(s)} ({th[2][i]} %)"
        rows.append(row)
    cols = ["Controller", "Gait opt."] + [f"{k} {v:g}" for k in ("RLR", "IC", "Surv") for v in SPEEDS]
    students = "; RL warm-start rows: 3 students x the sampler seeds" if seeded else ""
    finish(args, todo, results, rows, cols,
           f"Table 17 (ours (thesis); RLR/IC medians; first-spline, M = 10 000{students})", figure, "fig30.png")


if __name__ == "__main__":
    run_cli(main)
