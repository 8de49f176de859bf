"""The 1.5 m/s question: does an untuned gait explain why our naive MPC falls at 1.5 m/s?

Thesis Table 17: the naive MPC without gait optimisation survives 84.2 % of its episodes at a forward command of
1.5 m/s; ours survives 0 % [0, 19] with the baseline's trot (1.5 Hz, duty 0.6, ``mpc.baseline.BaselineConfig``),
which the thesis does not state. Here the same cell (naive warm start, forces only, first-spline, H = 10,
dt = 0.02 s, M = 10 000, flat, v_x = 1.5 m/s, v_y = omega_z = 0) runs over a grid of trot frequencies and duty
cycles on the same episodes and sampler seeds.

Written before running: the gait explains the gap if some (frequency, duty) cell survives with a 95 % interval
that reaches 84 % and is above the default gait's (paired survival difference excluding 0); it does not if every
cell's interval lies below 84 % at the medium scale. The grid is the whole sweep (no cell is picked after seeing
the data); the best cell is reported as exploratory.

    python -m experiments.naive_gait_sweep --scale small
    for k in 0 1; do python -m experiments.naive_gait_sweep --scale medium --shard $k/2 & done; wait
    python -m experiments.naive_gait_sweep --scale medium
"""

from __future__ import annotations

from pathlib import Path

from experiments.output import pyplot, save
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_tables import finish, med, paired, survival

SPEED = 1.5
FREQUENCIES = (1.5, 2.0, 2.5, 3.0)
DUTIES = (0.5, 0.6, 0.7)
DEFAULT = (1.5, 0.6)
THESIS_SURVIVAL = 84.2


def cell_name(f: float, d: float) -> str:
    return f"naive_f{f:g}_d{d:g}"


def cells() -> list[Cell]:
    return [Cell(cell_name(f, d), "naive_warm_start", vx=SPEED, naive_gait=(f, d),
                 row={"Frequency [Hz]": f, "Duty": d}) for f in FREQUENCIES for d in DUTIES]


def figure(results: dict, path: Path) -> None:
    """Survival (%) over the grid, one line per duty cycle, the thesis's 84.2 % dashed."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for i, d in enumerate(DUTIES):
        rates = [(results.get(cell_name(f, d)) or {}).get("survival", {}).get("rate") for f in FREQUENCIES]
        ax.plot(FREQUENCIES, [100 * r if r is not None else None for r in rates], "o-", color=f"C{i}",
                label=f"duty {d:g}")
    ax.axhline(THESIS_SURVIVAL, ls="--", color="k", lw=1, label="thesis, naive, 1.5 m/s")
    ax.set_xlabel("trot frequency [Hz]")
    ax.set_ylabel("survival [%]")
    ax.set_ylim(-3, 103)
    ax.legend(fontsize=7)
    ax.set_title("Naive MPC at 1.5 m/s over its gait", fontsize=9)
    save(fig, path)


def main() -> None:
    args = parse_args(__doc__, "naive_gait_sweep")
    todo = cells()
    results = run_cells(todo, args)
    rows = []
    base = cell_name(*DEFAULT)
    for f in FREQUENCIES:
        for d in DUTIES:
            s = results.get(cell_name(f, d))
            row = {"Frequency [Hz]": f, "Duty": d}
            if s is None or "skipped" in s:
                row["Survival"] = "skipped" if s else "-"
            else:
                row.update({"Survival": survival(s),
                            "Δ survival vs 1.5 Hz / 0.6 (paired)": paired(results, cell_name(f, d), base, "survived",
                                                                          digits=2),
                            "RL return / episode": med(s.get("rl_return"), 0),
                            "Δ return vs 1.5 Hz / 0.6 (paired)": paired(results, cell_name(f, d), base, "rl_return",
                                                                        digits=0),
                            "Initial cost": med(s.get("initial_cost")),
                            "|v_xy - cmd|": med(s.get("vel_error"), 3)})
            rows.append(row)
    cols = ["Frequency [Hz]", "Duty", "Survival", "Δ survival vs 1.5 Hz / 0.6 (paired)", "RL return / episode",
            "Δ return vs 1.5 Hz / 0.6 (paired)", "Initial cost", "|v_xy - cmd|"]
    finish(args, todo, results, rows, cols,
           f"Naive MPC at {SPEED:g} m/s over trot frequency and duty (thesis, default gait unstated: "
           f"{THESIS_SURVIVAL} % survival)", figure, "survival.png")


if __name__ == "__main__":
    main()
