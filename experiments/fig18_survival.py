"""Fig. 18 (thesis 7.1.3): survival of the four RL experts on the survival task.

    python -m experiments.fig18_survival --scale small     # about 2 min per policy on 2 cores
    python -m experiments.fig18_survival --scale thesis

Scenario ``survival`` (docs/eval.md): simple-task commands on the rough task's hardest terrain rows
(rugged, slopes, boxes, stairs), pushes of +-1 m/s every 4-6 s, friction 0.2-1.0, +-20 N wrench,
"high" observation noise. Per policy: survival overall, per terrain type and per row (Wilson
95 %). Thesis: neither base nor speed withstands it; climb is the most robust, "even outperforms
the rough task".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import percent_band, rate_cell, run

NAME, SCENARIO = "fig18_survival", "survival"
THESIS = {"base": "does not withstand", "rough": "below climb", "speed": "does not withstand", "climb": "best"}


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        row = {"policy": task, "survival [95 % CI]": rate_cell(res["survival"])}
        row.update({t: f"{100 * c['rate']:.0f} % ({c['k']}/{c['n']})" if c["n"] else "-"
                    for t, c in res["per_type"].items()})
        row["thesis"] = THESIS[task]
        rows.append(row)
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    tasks = list(results)
    types = list(results[tasks[0]]["per_type"])
    labels = ["all"] + types
    fig, ax = plt.subplots(figsize=(10, 4))
    width = 0.8 / len(tasks)
    for i, t in enumerate(tasks):
        cells = [results[t]["survival"]] + [results[t]["per_type"][k] for k in types]
        r, lo, hi = percent_band(cells)
        ax.bar(np.arange(len(labels)) + (i - (len(tasks) - 1) / 2) * width, r, width,
               yerr=[r - lo, hi - r], capsize=2, label=t)
    ax.set_xticks(range(len(labels)), labels)
    ax.set_ylabel("survival [%] (Wilson 95 %)")
    ax.set_ylim(0, 105)
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    n = results[tasks[0]]["episodes"]
    ax.set_title(f"Fig. 18: survival task, {n} episodes per policy (thesis: climb most robust)", fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 18, scale {scale}: survival task", figure, "fig18.png", argv)


if __name__ == "__main__":
    main()
