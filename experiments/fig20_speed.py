"""Fig. 20: survival probability of the four RL experts vs commanded forward speed, flat ground.

    python -m experiments.fig20_speed --scale small     # about 1 min per policy on 2 cores
    python -m experiments.fig20_speed --scale thesis

Scenario ``speed`` (docs/eval.md): (v, 0, 0) for 15 s, v = 0.25 ... 2.5 m/s, flat, no disturbance.
Per policy and speed: survival (Wilson 95 %) and achieved speed (mean, 95 % CI); per policy the
speed where survival first drops below 90 % and its ratio to the policy's training maximum.
Thesis: speed goes fastest but is the least reliable; base reaches "almost twice the speed at
which it was trained" (1 m/s); rough falls above 0.8 m/s; climb does not fall but slows down.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import mean_cell, num, run

NAME, SCENARIO = "fig20_speed", "speed"
TRAINED_MAX = {"base": 1.0, "rough": 0.8, "speed": 2.1, "climb": 0.5}
"""[m/s] the highest forward command of each task (Table 3)."""
THESIS = {"base": "~2x its trained speed", "rough": "falls above 0.8 m/s", "speed": "fastest, least reliable",
          "climb": "never falls, slows down"}


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        c = res["survival_crossing"]
        row = {"policy": task, "trained max [m/s]": TRAINED_MAX[task],
               "survival >= 90 % up to [m/s]": f"{num(c['speed'], '.2f')} [{num(c['ci95'][0], '.2f')}, "
                                               f"{num(c['ci95'][1], '.2f')}]",
               "x trained max": num(c["speed"] / TRAINED_MAX[task], ".2f"),
               "max achieved v_x [m/s]": mean_cell(res["max_achieved_v_x"])}
        row.update({f"surv. {s['command_v_x']:g}": f"{100 * s['survival']['rate']:.0f} %" for s in res["per_speed"]})
        row["thesis"] = THESIS[task]
        rows.append(row)
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    for task, res in results.items():
        v = np.array(res["speeds"])
        s = np.array([100 * r["survival"]["rate"] for r in res["per_speed"]])
        lo = np.array([100 * r["survival"]["ci95"][0] for r in res["per_speed"]])
        hi = np.array([100 * r["survival"]["ci95"][1] for r in res["per_speed"]])
        line = ax0.errorbar(v, s, yerr=[s - lo, hi - s], marker="o", capsize=3, label=task)
        ax0.axvline(TRAINED_MAX[task], color=line[0].get_color(), ls=":", lw=1)
        a = np.array([np.nan if r["achieved_v_x"]["mean"] is None else r["achieved_v_x"]["mean"]
                      for r in res["per_speed"]])
        ax1.plot(v, a, "o-", label=task)
    ax0.set_xlabel("commanded v_x [m/s] (dotted: trained maximum)")
    ax0.set_ylabel("survival [%] (Wilson 95 %)")
    ax0.set_ylim(-5, 105)
    vmax = max(max(r["speeds"]) for r in results.values())
    ax1.plot([0, vmax], [0, vmax], color="0.6", lw=1)
    ax1.set_xlabel("commanded v_x [m/s]")
    ax1.set_ylabel("achieved v_x [m/s] (mean over episodes)")
    for ax in (ax0, ax1):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    n = next(iter(results.values()))["episodes_per_condition"]
    fig.suptitle(f"Fig. 20: forward-speed sweep, flat, {n} episodes per speed and policy", fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 20, scale {scale}: survival vs forward speed", figure, "fig20.png",
        argv)


if __name__ == "__main__":
    main()
