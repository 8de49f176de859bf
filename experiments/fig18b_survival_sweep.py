"""Fig. 18b (ours, beside thesis 7.1.3): survival of the four RL experts vs terrain difficulty.

    python -m experiments.fig18b_survival_sweep --scale small     # about 1-2 min per policy on 2 cores

Scenario ``survival_sweep`` (docs/eval.md): the survival task's commands and terrain types over the
rough task's *whole* difficulty range, 8 rows from 0 (nearly flat) to 1 (``survival``'s hardest
row), with the rough task's own disturbances (pushes of +-0.5 m/s every 8-12 s, friction 0.4-0.8,
+-10 N wrench, "high" observation noise). ``survival`` itself (Fig. 18: difficulty 0.7-1, doubled
disturbances) keeps every expert below 4 %; this sweep shows where each one still stands. Per
policy: survival per difficulty row (Wilson 95 %) and the difficulty where it first drops below
50 %. Thesis: neither base nor speed withstands the perturbations; climb is the most robust,
"even outperforms the rough task".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import percent_band, rate_cell, run

NAME, SCENARIO = "fig18b_survival_sweep", "survival_sweep"
THESIS = {"base": "does not withstand", "rough": "below climb", "speed": "does not withstand", "climb": "best"}


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        c = res["survival_crossing_50"]
        row = {"policy": task, "survival, all rows [95 % CI]": rate_cell(res["survival"]),
               "50 % crossing (difficulty) [95 % CI]":
                   f"{c['rough_difficulty']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]"}
        row.update({f"d = {r['rough_difficulty']:.2f}": f"{100 * r['survival']['rate']:.0f} % "
                    f"({r['survival']['k']}/{r['survival']['n']})" if r["survival"]["n"] else "-"
                    for r in res["per_row"]})
        row["thesis"] = THESIS[task]
        rows.append(row)
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for task, res in results.items():
        d = np.array([r["rough_difficulty"] for r in res["per_row"]])
        cells = [r["survival"] for r in res["per_row"]]
        rate, lo, hi = percent_band(cells)
        line, = ax.plot(d, rate, "o-", label=task)
        ax.fill_between(d, lo, hi, color=line.get_color(), alpha=0.12)
    ax.axhline(50, color="k", lw=0.6, ls=":")
    ax.axvspan(0.7, 1.0, color="0.93", zorder=0, label="survival scenario's rows")
    ax.set_xlabel("terrain difficulty (fraction of the rough task's ranges)")
    ax.set_ylabel("survival [%] (Wilson 95 %)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    n = results[next(iter(results))]["episodes"]
    ax.set_title(f"Survival vs terrain difficulty, rough task's disturbances, {n} episodes per policy", fontsize=9)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 18b, scale {scale}: survival vs terrain difficulty", figure,
        "fig18b.png", argv)


if __name__ == "__main__":
    main()
