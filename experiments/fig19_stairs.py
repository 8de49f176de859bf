"""Fig. 19: staircase performance of the four RL experts vs step height (5-50 cm).

    python -m experiments.fig19_stairs --scale small     # about 2 min per policy on 2 cores
    python -m experiments.fig19_stairs --scale thesis

Scenario ``stairs`` (docs/eval.md): a 6-step ``stairs_up`` flight per height, 0.3-0.5 m/s
forward, no noise or perturbation. Per policy and height: reached the top (Wilson 95 %) and the
fraction of the flight climbed; per policy the height where success first drops below 50 %.
Thesis: "not particularly good"; performance drops after 25 cm, even for climb; rough does poorly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import num, run

NAME, SCENARIO = "fig19_stairs", "stairs"


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        row = {"policy": task}
        row.update({f"{100 * r['step_height']:.0f} cm": f"{100 * r['success']['rate']:.0f} % ({r['success']['k']}/"
                    f"{r['success']['n']})" for r in res["per_height"]})
        c = res["success_crossing_50"]
        row["success < 50 % from [cm]"] = f"{num(100 * c['step_height'], '.0f')} [{num(100 * c['ci95'][0], '.0f')}, " \
                                          f"{num(100 * c['ci95'][1], '.0f')}]"
        row["thesis"] = "drops after 25 cm" + (" (best)" if task == "climb" else "")
        rows.append(row)
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for task, res in results.items():
        h = 100 * np.array([r["step_height"] for r in res["per_height"]])
        s = np.array([100 * r["success"]["rate"] for r in res["per_height"]])
        lo = np.array([100 * r["success"]["ci95"][0] for r in res["per_height"]])
        hi = np.array([100 * r["success"]["ci95"][1] for r in res["per_height"]])
        ax.errorbar(h, s, yerr=[s - lo, hi - s], marker="o", capsize=3, label=task)
    ax.axvline(25, color="0.6", ls="--", lw=1, label="thesis: drop after 25 cm")
    ax.set_xlabel("step height [cm]")
    ax.set_ylabel("reached the top [%] (Wilson 95 %)")
    ax.set_ylim(-5, 105)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    n = next(iter(results.values()))["episodes_per_condition"]
    ax.set_title(f"Fig. 19: stairs, {n} episodes per height and policy", fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 19, scale {scale}: reached the top of a 6-step flight per step height",
        figure, "fig19.png", argv)


if __name__ == "__main__":
    main()
