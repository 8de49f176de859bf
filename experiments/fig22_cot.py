"""Fig. 22: cost of transport (eq. 4.3.7) of the four RL experts vs forward speed, flat ground.

    python -m experiments.fig22_cot --scale small     # about 40 s per policy on 2 cores
    python -m experiments.fig22_cot --scale thesis

Scenario ``cot`` (docs/eval.md): (v, 0, 0) for 15 s, v = 0.25 ... 2.5 m/s; per episode the energy
sum_t sum_j max(tau qdot + 0.3 tau^2, 0) dt over m g times the distance walked, after a 2 s
settle. Per policy and speed: mean CoT (95 % CI over episodes) at the achieved speed. Thesis:
like Yang et al. 2021's A1, "from 2 at 0.5 m/s, down to slightly less than 1 at 2.5 m/s"; speed
has the highest CoT up to 1.1 m/s, then drops at its trot -> trot-gallop transition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import run

NAME, SCENARIO = "fig22_cot", "cot"


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        for r in res["per_speed"]:
            c, a = r["cot"], r["achieved_speed_h"]
            if not c["n"]:
                cot = "- (no episode past the settle)"
            else:
                cot = f"{c['mean']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}] (n = {c['n']})" \
                    if c["ci95"][0] is not None else f"{c['mean']:.2f} (n = {c['n']})"
            rows.append({"policy": task, "commanded v_x [m/s]": r["command_v_x"],
                         "achieved planar speed [m/s]": "-" if a["mean"] is None else f"{a['mean']:.2f}",
                         "CoT [95 % CI]": cot,
                         "power [W]": "-" if r["power_w"]["mean"] is None else f"{r['power_w']['mean']:.0f}",
                         "survival": f"{100 * r['survival']['rate']:.0f} % ({r['survival']['k']}/{r['survival']['n']})",
                         "thesis": {0.5: "~2", 2.5: "slightly < 1"}.get(r["command_v_x"], "")})
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for task, res in results.items():
        rows = [r for r in res["per_speed"] if r["cot"]["n"]]
        v = np.array([r["achieved_speed_h"]["mean"] for r in rows], dtype=float)
        c = np.array([r["cot"]["mean"] for r in rows], dtype=float)
        lo = np.array([r["cot"]["ci95"][0] if r["cot"]["ci95"][0] is not None else r["cot"]["mean"] for r in rows])
        hi = np.array([r["cot"]["ci95"][1] if r["cot"]["ci95"][1] is not None else r["cot"]["mean"] for r in rows])
        ax.errorbar(v, c, yerr=[c - lo, hi - c], marker="o", capsize=3, label=task)
    ax.plot([0.5, 2.5], [2.0, 1.0], "s--", color="0.5", label="thesis text: 2 at 0.5, <1 at 2.5 m/s")
    ax.set_xlabel("achieved speed |v_xy| [m/s]")
    ax.set_ylabel("cost of transport")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    n = next(iter(results.values()))["episodes_per_condition"]
    ax.set_title(f"Fig. 22: CoT vs speed, flat, {n} episodes per speed and policy", fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 22, scale {scale}: cost of transport vs speed", figure, "fig22.png",
        argv)


if __name__ == "__main__":
    main()
