"""Table 14 and Figs. 26-27 (thesis 7.3.2): RL warm start vs naive warm start vs RL baseline for the six
(p, F) encodings, H = 10, dt = 0.02 s, M = 10 000, the MPC optimising the forces only, simple task.

    python experiments/table14_warm_start_encodings.py --scale small
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.warm_start_common import (  # noqa: E402
    Cell,
    med,
    parse_args,
    run_cells,
    survival,
    write_config,
    write_table,
)
from dls_quadruped.core.json_io import write_json  # noqa: E402

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
    """Figs. 26-27: initial cost and rollout cost per encoding, medians with quartile bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{p}-{F}" for p, F in ENCODINGS]
    for ax, key, title in ((axes[0], "initial_cost", "Fig. 26: initial (state) cost"),
                           (axes[1], "rollout_cost", "Fig. 27: rollout cost")):
        for off, ctrl, color in ((-0.2, "rl_warm_start", "C0"), (0.2, "naive_warm_start", "C1")):
            for i, (p, F) in enumerate(ENCODINGS):
                s = results.get(f"{ctrl}_{p}-{F}", {})
                m = s.get(key)
                if not m or m.get("n", 0) == 0:
                    continue
                ax.errorbar(i + off, m["median"], yerr=[[m["median"] - m["q1"]], [m["q3"] - m["median"]]], fmt="o",
                            color=color, capsize=3, label=ctrl if i == 0 else None)
        ax.set_xticks(range(len(labels)), labels, rotation=30)
        ax.set_yscale("log")
        ax.set_title(title + " (median, IQR)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__, "table14_warm_start")
    todo = cells()
    results = run_cells(todo, args)
    rows = []
    for c in todo:
        s = results.get(c.name)
        if s is None:
            continue
        key = (c.controller, c.row["p"], c.row["F"])
        th = (None, None, None) if c.naive_share else THESIS.get(key, (None, None, None))
        row = dict(c.row)
        if "skipped" in s:
            row["RL reward"] = f"skipped: {s['skipped']}"
        else:
            won = s.get("warm_start_won") or {}
            row.update({"RL reward": med(s["rl_reward"], 3), "Initial cost": med(s["initial_cost"]),
                        "Rollout cost": med(s.get("rollout_cost")), "Survival": survival(s),
                        "|v_xy - cmd|": med(s["vel_error"], 3),
                        "student won": f"{100 * won.get('0', 0.0):.0f} %" if c.naive_share else ""})
        row.update({"thesis RL reward": th[0] or "-", "thesis initial": th[1] or "-", "thesis rollout": th[2] or "-"})
        rows.append(row)
    cols = ["Controller", "p", "F", "RL reward", "Initial cost", "Rollout cost", "Survival", "|v_xy - cmd|",
            "student won", "thesis RL reward", "thesis initial", "thesis rollout"]
    write_table(rows, cols, args.out / "table", f"Table 14 ({args.scale}: {args.episodes} episodes x {args.seconds:g} s "
                f"per cell; median [q1, q3] over every step; M = 10 000, H = 10, dt = 0.02 s, F only)")
    write_json(results, args.out / "results.json", indent=1)
    figure(results, args.out / "fig26_27.png")
    write_config(args, todo)
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()
