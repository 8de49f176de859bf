"""Table 15 and Fig. 28 (thesis 7.3.3): prediction horizon (dt, H) for the RL and naive warm starts,
first-spline, M = 10 000, forces only, simple task; Fig. 28 = the chosen sample's cost at each horizon
step (median over the recorded solves, log scale).

    python experiments/table15_horizon.py --scale small
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.warm_start_common import (
    Cell,
    finish,
    med,
    paired,
    parse_args,
    pyplot,
    run_cells,
    save,
    survival,
    tabulate,
)

GRID = [(0.02, 5), (0.04, 5), (0.02, 10), (0.02, 15), (0.04, 10), (0.04, 15)]
THESIS = {  # (controller, dt, H): (RL reward, initial cost)
    ("rl_warm_start", 0.02, 5): (2.355, 14.62), ("rl_warm_start", 0.04, 5): (2.348, 25.04),
    ("rl_warm_start", 0.02, 10): (2.346, 32.93), ("rl_warm_start", 0.02, 15): (2.329, 75.92),
    ("rl_warm_start", 0.04, 10): (2.329, 128.4), ("rl_warm_start", 0.04, 15): (2.238, 477.2),
    ("naive_warm_start", 0.02, 5): (2.258, 31.41), ("naive_warm_start", 0.04, 5): (2.255, 31.41),
    ("naive_warm_start", 0.02, 10): (2.248, 28.61), ("naive_warm_start", 0.02, 15): (2.233, 41.11),
    ("naive_warm_start", 0.04, 10): (2.179, 79.81), ("naive_warm_start", 0.04, 15): (1.756, 408.8),
}


def cells() -> list[Cell]:
    return [Cell(f"{ctrl}_dt{dt:g}_H{h}", ctrl, {"dt": dt, "horizon": h},
                 row={"Controller": ctrl, "dt [s]": dt, "H": h, "Time H. [s]": round(dt * h, 2)})
            for ctrl in ("rl_warm_start", "naive_warm_start") for dt, h in GRID]


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, ctrl in zip(axes, ("rl_warm_start", "naive_warm_start")):
        for i, (dt, h) in enumerate(GRID):
            s = results.get(f"{ctrl}_dt{dt:g}_H{h}", {})
            hc = s.get("horizon_cost")
            if not hc:
                continue
            ax.plot(range(1, h + 1), [m["median"] for m in hc], "o-", color=f"C{i}", label=f"dt {dt:g}, H {h}")
        ax.set_yscale("log")
        ax.set_xlabel("horizon step k")
        ax.set_title(f"Fig. 28: {ctrl}, chosen sample's state cost per step (median)", fontsize=9)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("cost of step k")
    save(fig, path)


def columns_with(results: dict):
    """The table's columns; an RL warm start's paired difference is against the naive warm start of the
    same (dt, H) on the same episodes."""

    def columns(c: Cell, s: dict) -> dict:
        hc = s.get("horizon_cost") or []
        ratio = f"{hc[-1]['median'] / hc[0]['median']:.1f}" if hc and hc[0]["median"] else "-"
        ref = c.name.replace("rl_warm_start", "naive_warm_start") if c.controller == "rl_warm_start" else None
        return {"RL reward": med(s["rl_reward"], 3), "Initial cost": med(s["initial_cost"]),
                "Δ initial vs naive (paired)": paired(results, c.name, ref, "initial_cost") if ref else "",
                "Rollout cost (state)": med(s.get("rollout_cost")), "Rollout J (full)": med(s.get("rollout_cost_full")),
                "Survival": survival(s), "last/first step cost": ratio}

    return columns


def thesis(c: Cell) -> dict:
    th = THESIS.get((c.controller, c.row["dt [s]"], c.row["H"]), (None, None))
    return {"thesis RL reward": th[0] or "-", "thesis initial": th[1] or "-"}


def main() -> None:
    args = parse_args(__doc__, "table15_horizon")
    todo = cells()
    results = run_cells(todo, args)
    cols = ["Controller", "dt [s]", "H", "Time H. [s]", "RL reward", "Initial cost", "Δ initial vs naive (paired)",
            "Rollout cost (state)", "Rollout J (full)", "Survival", "last/first step cost", "thesis RL reward",
            "thesis initial"]
    finish(args, todo, results, tabulate(todo, results, columns_with(results), thesis), cols,
           "Table 15 (first-spline, M = 10 000, F only)", figure, "fig28.png")


if __name__ == "__main__":
    main()
