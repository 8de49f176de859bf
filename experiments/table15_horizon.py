"""Table 15 and Fig. 28 (thesis 7.3.3): prediction horizon (dt, H) for the RL and naive warm starts,
first-spline, M = 10 000, forces only, simple task; Fig. 28 = the chosen sample's cost at each horizon
step (median over the recorded solves, log scale).

    python experiments/table15_horizon.py --scale small
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.warm_start_common import Cell, med, parse_args, run_cells, survival, write_config, write_table  # noqa: E402
from dls_quadruped.core.json_io import write_json  # noqa: E402

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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
        ax.set_title(f"Fig. 28: {ctrl}, chosen sample's cost per step (median)", fontsize=9)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("cost of step k")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__, "table15_horizon")
    todo = cells()
    results = run_cells(todo, args)
    rows = []
    for c in todo:
        s = results.get(c.name)
        if s is None:
            continue
        row = dict(c.row)
        if "skipped" in s:
            row["RL reward"] = f"skipped: {s['skipped']}"
        else:
            hc = s.get("horizon_cost") or []
            row.update({"RL reward": med(s["rl_reward"], 3), "Initial cost": med(s["initial_cost"]),
                        "Rollout cost": med(s.get("rollout_cost")), "Survival": survival(s),
                        "last/first step cost": (f"{hc[-1]['median'] / hc[0]['median']:.1f}" if hc and hc[0]["median"] else "-")})
        th = THESIS.get((c.controller, c.row["dt [s]"], c.row["H"]), (None, None))
        row.update({"thesis RL reward": th[0], "thesis initial": th[1]})
        rows.append(row)
    cols = ["Controller", "dt [s]", "H", "Time H. [s]", "RL reward", "Initial cost", "Rollout cost", "Survival",
            "last/first step cost", "thesis RL reward", "thesis initial"]
    write_table(rows, cols, args.out / "table", f"Table 15 ({args.scale}: {args.episodes} episodes x {args.seconds:g} s "
                f"per cell; median [q1, q3]; first-spline, M = 10 000, F only)")
    write_json(results, args.out / "results.json", indent=1)
    figure(results, args.out / "fig28.png")
    write_config(args, todo)
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()
