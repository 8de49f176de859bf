"""Fig. 17 (thesis 7.1.2): the four RL experts on the simple task, base-task (Table-4) reward.

    python -m experiments.fig17_simple_task --scale small     # about 1 min per policy on 2 cores
    python -m experiments.fig17_simple_task --scale thesis

Scenario ``simple`` (docs/eval.md): one command per 15 s episode, v_x in [0.3, 0.6] m/s, v_y in
[-0.2, 0.2] m/s, omega_z in [-0.5, 0.5] rad/s, flat, no disturbance. Per policy: the per-step
Table-4 reward (per-episode mean, 95 % interval over episodes), survival, tracking error, and
base's reward relative to it. Thesis: base is best, "at least 20 % better" than the others.
"""

from __future__ import annotations

from pathlib import Path

from experiments.output import pyplot, save
from experiments.rl_common import mean_cell, num, rate_cell, run

NAME, SCENARIO = "fig17_simple_task", "simple"
THESIS = {"base": "best", "rough": "general-purpose, 2nd", "speed": "specialised, lower", "climb": "specialised, lower"}


def rows_of(results: dict) -> list[dict]:
    base = results.get("base", {}).get("reward", {}).get("per_episode", {}).get("mean")
    rows = []
    for task, res in results.items():
        r = res["reward"]["per_episode"]
        gap = "-" if base is None or task == "base" or not r["mean"] else f"{100 * (base / r['mean'] - 1):+.1f} %"
        rows.append({"policy": task, "reward per step [95 % CI]": mean_cell(r),
                     "pooled reward per step": num(res["reward"]["per_step"]),
                     "survival": rate_cell({**res["survival"], "k": res["survival"].get("survived")}),
                     "median tracking error v_xy [m/s]": num(res["tracking"]["vxy_error"]["median"]),
                     "base vs this": gap, "thesis": THESIS[task]})
    return rows


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    tasks = list(results)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 3.8))
    m = [results[t]["reward"]["per_episode"]["mean"] or 0.0 for t in tasks]
    ci = [results[t]["reward"]["per_episode"]["ci95"] for t in tasks]
    err = [[v - (c[0] if c[0] is not None else v) for v, c in zip(m, ci)],
           [(c[1] if c[1] is not None else v) - v for v, c in zip(m, ci)]]
    ax0.bar(tasks, m, yerr=err, capsize=4)
    ax0.set_ylabel("Table-4 reward per step (mean over episodes, 95 % CI)")
    s = [100 * results[t]["survival"]["rate"] for t in tasks]
    lo = [100 * results[t]["survival"]["ci95"][0] for t in tasks]
    hi = [100 * results[t]["survival"]["ci95"][1] for t in tasks]
    ax1.bar(tasks, s, yerr=[[a - b for a, b in zip(s, lo)], [b - a for a, b in zip(s, hi)]], capsize=4)
    ax1.set_ylabel("survival [%] (Wilson 95 %)")
    ax1.set_ylim(0, 105)
    n = results[tasks[0]]["episodes"]
    fig.suptitle(f"Fig. 17: simple task, {n} episodes per policy (thesis: base >= 20 % better)", fontsize=10)
    save(fig, path)


def main(argv: list[str] | None = None) -> None:
    run(__doc__, NAME, SCENARIO, rows_of, "Fig. 17, scale {scale}: simple task, Table-4 reward", figure, "fig17.png",
        argv)


if __name__ == "__main__":
    main()
