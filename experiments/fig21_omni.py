"""Fig. 21: omnidirectional capability, the 90 %-success isoline of the four RL experts.

    python -m experiments.fig21_omni --scale small     # about 2 min per policy on 2 cores
    python -m experiments.fig21_omni --scale thesis

Scenario ``omni`` (docs/eval.md): 8 directions x magnitudes 0.25-2 m/s, flat, no disturbance;
success = survived and |mean v_xy - cmd| <= max(25 % |cmd|, 0.1 m/s). Per policy and direction:
the outer edge of the region where success is at least 90 % (95 % interval), and the same for
survival alone (the thesis does not define its "succeed"). Thesis: rough,
speed and climb match their training commands; base goes "50 % faster in all directions" than
its 1 m/s training range.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import mean_cell, num, run

NAME, SCENARIO = "fig21_omni", "omni"
THESIS = {"base": "~1.5 m/s in every direction", "rough": "its +-0.8 m/s disc", "speed": "forward to ~2 m/s",
          "climb": "forward 0.3-0.5 m/s"}


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        row = {"policy": task, "mean success isoline [m/s]": mean_cell(res["isoline_success_mean"], ".2f"),
               "mean survival isoline [m/s]": mean_cell(res["isoline_survival_mean"], ".2f")}
        for iso in res["isolines"]:
            cells = []
            for s in (iso["success"], iso["survival"]):
                mark = ">" if s["beyond_grid"] else ("<" if s["below_grid"] else "")
                lo, hi = (num(x, ".2f") for x in s["ci95"])
                cells.append(f"{mark}{num(s['magnitude'], '.2f')} [{lo}, {hi}]")
            row[f"{iso['direction_deg']:g} deg success / survival"] = " / ".join(cells)
        row["thesis"] = THESIS[task]
        rows.append(row)
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig = plt.figure(figsize=(5.5, 5))
    ax = fig.add_subplot(projection="polar")
    for task, res in results.items():
        d = list(res["directions_deg"])
        th = np.deg2rad(np.array(d + d[:1], dtype=float))
        color = None
        for key, style in (("success", "o-"), ("survival", "s--")):
            m = np.array([i[key]["magnitude"] for i in res["isolines"]], dtype=float)
            lo = np.array([i[key]["ci95"][0] for i in res["isolines"]], dtype=float)
            hi = np.array([i[key]["ci95"][1] for i in res["isolines"]], dtype=float)
            line, = ax.plot(th, np.r_[m, m[:1]], style, color=color, label=f"{task}: {key}")
            color = line.get_color()
            ax.fill_between(th, np.r_[lo, lo[:1]], np.r_[hi, hi[:1]], color=color, alpha=0.12)
    ax.plot(np.linspace(0, 2 * np.pi, 100), np.ones(100), color="0.6", lw=1, label="1 m/s (base training)")
    ax.set_rmax(max(max(r["magnitudes"]) for r in results.values()))
    ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.85, -0.05))
    n = next(iter(results.values()))["episodes_per_condition"]
    ax.set_title(f"Fig. 21: 90 % isolines [m/s] of success (tracked within 25 %) and survival,\n"
                 f"{n} episodes per cell (0 deg forward, 90 deg left)",
                 fontsize=9)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 21, scale {scale}: 90 %-success isoline per direction", figure,
        "fig21.png", argv)


if __name__ == "__main__":
    main()
