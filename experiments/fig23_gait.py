"""Fig. 23 (a: base, b: speed): gait (contact pattern) and step frequency vs forward speed.

    python -m experiments.fig23_gait --scale small     # about 40 s per policy on 2 cores
    python -m experiments.fig23_gait --scale thesis

Scenario ``gait`` (docs/eval.md): (v, 0, 0) for 15 s, v = 0.25 ... 2.5 m/s, flat; per policy and
speed the step frequency (the action's f and the feet's touch-downs per second), duty factor and
the contact agreement of the diagonal / lateral / front / rear leg pairs (95 % CI over
episodes), and one 2 s Hildebrand diagram per speed (``<out>/<task>/gait.png``). The thesis
shows base and speed: base keeps a regular trot at every speed; speed trots at low speed and
above 1.1 m/s switches to a hybrid (front pair trot-like, rear pair gallop-like), its frequency
rising sharply at its maximum; no flying gait.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output import pyplot, save
from experiments.rl_common import run

NAME, SCENARIO = "fig23_gait", "gait"
PAIRS = ("diagonal", "lateral", "front", "rear")


def _m(x: dict, fmt: str = ".2f") -> str:
    return "-" if not x["n"] or x["mean"] is None else format(x["mean"], fmt)


def rows_of(results: dict) -> list[dict]:
    rows = []
    for task, res in results.items():
        for r in res["per_speed"]:
            f = r["f_contacts"]
            ci = "" if not f["n"] or f["ci95"][0] is None else f" [{f['ci95'][0]:.2f}, {f['ci95'][1]:.2f}]"
            rows.append({"policy": task, "commanded v_x [m/s]": r["command_v_x"], "f action [Hz]": _m(r["f_policy"]),
                         "touch-downs/s [95 % CI]": _m(f) + ci,
                         "contact rising edges/s": _m(r["contact_rising_edges_per_s"]),
                         "duty (contacts)": _m(r["duty_contacts"]),
                         **{f"sync {p}": _m(r["sync"][p]) for p in PAIRS}, "episodes past settle": f["n"],
                         "survival": f"{100 * r['survival']['rate']:.0f} %"})
    return rows


def get(row: dict, key: str, sub: str | None = None) -> float:
    """A row's mean of ``key`` (or ``key[sub]``); NaN where it is missing."""
    cell = row[key] if sub is None else row[key][sub]
    return np.nan if cell["mean"] is None else cell["mean"]


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    for task, res in results.items():
        v = np.array([r["command_v_x"] for r in res["per_speed"]])
        line, = ax0.plot(v, [get(r, "f_contacts") for r in res["per_speed"]], "o-", label=f"{task}: touch-downs/s")
        ax0.plot(v, [get(r, "f_policy") for r in res["per_speed"]], "--", color=line.get_color(), label=f"{task}: f")
        ax1.plot(v, [get(r, "sync", "diagonal") for r in res["per_speed"]], "o-", color=line.get_color(),
                 label=f"{task}: diagonal")
        ax1.plot(v, [get(r, "sync", "rear") for r in res["per_speed"]], "s:", color=line.get_color(),
                 label=f"{task}: rear pair")
    ax0.set_ylabel("step frequency [Hz]")
    ax1.set_ylabel("pair contact agreement (1: in phase)")
    ax1.set_ylim(0, 1.05)
    for ax in (ax0, ax1):
        ax.axvline(1.1, color="0.6", ls="--", lw=1)
        ax.set_xlabel("commanded v_x [m/s] (dashed: 1.1 m/s, the thesis's transition)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    n = next(iter(results.values()))["episodes_per_condition"]
    fig.suptitle(f"Fig. 23: gait vs speed, {n} episodes per speed and policy (diagrams: <task>/gait.png)",
                 fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 23, scale {scale}: gait vs speed", figure, "fig23.png", argv)


if __name__ == "__main__":
    main()
