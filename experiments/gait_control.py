"""The gait/warm-start control: which part of the RL - naive warm-start differences the student's gait and
footholds carry, and which its forces (the plan: docs/experiments/gait_control_plan.md).

The RL warm start hands the MPC the student's gait, footholds *and* forces; the naive one a periodic trot, the
heuristic footholds and its own previous forces. Two crossed arms (``closed_loop/split_warm_start.py``) take one
part from each, so four arms run on the same scheduled episodes (first-spline, H = 10, dt = 0.02 s, the MPC on the
forces only):

====  ==========================  ==================  ==================
arm   controller                  gait, footholds     force warm start
====  ==========================  ==================  ==================
RL    ``rl_warm_start``           student             student
G     ``rl_gait_naive_forces``    student             naive
F     ``naive_gait_rl_forces``    naive               student
N     ``naive_warm_start``        naive               naive
====  ==========================  ==================  ==================

RL, G and F run once per training seed's student (``--seed-students``, three students); per outcome (the initial
cost as Table 14 reports it, its per-episode mean, the reward per step, survival, the return per episode) and per
episode and student:

* total ``RL - N``;
* the gait's part with the naive forces ``G - N`` and with the student's ``RL - F``, and their mean, the gait's
  Shapley share ``phi_gait = ((G - N) + (RL - F)) / 2``;
* the forces' part ``F - N``, ``RL - G`` and ``phi_forces = ((F - N) + (RL - G)) / 2``;
* the interaction ``RL - G - F + N`` (zero when the parts add up).

``phi_gait + phi_forces = RL - N`` exactly. Intervals: paired bootstrap over episodes and students (the three
students are the same in every student arm; N is shared by them), ``eval.metrics.paired_difference``. Labels by
the plan's margins (:data:`MARGINS`)::

    python -m experiments.gait_control --scale thesis --sampler-seeds 1 --com-height 0.357 \\
        --seed-students runs/students_seeds --out docs/experiments/gait_control
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.cli import run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from experiments.output import pyplot, save, write_table
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import SEED_STUDENTS, merge_seed_rows, seed_student_cells
from experiments.warm_start_tables import finish, med, survival

SAMPLER = {"encoding_p": "first", "encoding_F": "spline"}
ARMS = {"RL": "rl_warm_start", "G": "rl_gait_naive_forces", "F": "naive_gait_rl_forces", "N": "naive_warm_start"}
"""Arm letter -> controller (module docstring)."""
OUTCOMES = (("initial cost (Table 14's: median per episode)", "initial_cost", 1),
            ("initial cost (mean per episode)", "initial_cost_mean", 1),
            ("reward per step", "rl_reward", 3), ("survival", "survived", 2), ("return per episode", "rl_return", 1))
MARGINS = {"initial_cost": 5.0, "initial_cost_mean": 5.0, "rl_reward": 0.02, "survived": 0.10}
"""Equivalence margins, fixed by the plan before the run: a contrast whose interval lies inside +- margin is
"within the margin" (the part carries none of the difference, to the margin); the return has none."""
CONTRASTS = (("total RL - N", {"RL": 1, "N": -1}),
             ("gait, naive forces: G - N", {"G": 1, "N": -1}),
             ("gait, student forces: RL - F", {"RL": 1, "F": -1}),
             ("gait (Shapley): (G - N + RL - F) / 2", {"G": 0.5, "N": -0.5, "RL": 0.5, "F": -0.5}),
             ("forces, naive gait: F - N", {"F": 1, "N": -1}),
             ("forces, student gait: RL - G", {"RL": 1, "G": -1}),
             ("forces (Shapley): (F - N + RL - G) / 2", {"F": 0.5, "N": -0.5, "RL": 0.5, "G": -0.5}),
             ("interaction: RL - G - F + N", {"RL": 1, "G": -1, "F": -1, "N": 1}))
"""Each contrast as weights on the arms (they sum to 0)."""


def cells(students: Path, only: list[str] | None = None) -> tuple[list[Cell], dict[str, list[str]]]:
    """(cells to run, {merged student row: its students' cells}), one row per arm."""
    base = [Cell(f"{ARMS[a]}_first-spline", ARMS[a], SAMPLER, row={"arm": a, "Controller": ARMS[a]}) for a in ARMS]
    return seed_student_cells(base, students, only, SEED_STUDENTS)


def arm_values(results: dict, key: str) -> dict[str, np.ndarray] | None:
    """Per arm the (T, E) per-episode values of ``key``: students x episodes for the student arms (their rows
    merged by ``merge_training_seeds``); N's mean over its sampler seeds, repeated for every student. None if an
    arm is missing, skipped or lacks ``key``."""
    out = {}
    for a, ctrl in ARMS.items():
        s = results.get(f"{ctrl}_first-spline") or {}
        if key not in s.get("per_episode", {}):
            return None
        out[a] = np.atleast_2d(np.asarray(s["per_episode"][key], dtype=float))
    with np.errstate(all="ignore"):
        out["N"] = np.nanmean(out["N"], axis=0, keepdims=True)
    t = {v.shape[0] for a, v in out.items() if a != "N"}
    if len(t) != 1:
        raise ValueError(f"the student arms have different student counts {sorted(t)}")
    out["N"] = np.repeat(out["N"], t.pop(), axis=0)
    return out


def contrast(values: dict[str, np.ndarray], weights: dict[str, float], student: int | None = None) -> dict:
    """``sum_a w_a arm_a`` per episode and student, as ``paired_difference`` of its positive and negative parts
    (students resampled together); ``student``: that student's row alone."""
    from dls_quadruped.eval.metrics import paired_difference

    rows = slice(None) if student is None else slice(student, student + 1)
    pos = sum(w * values[a][rows] for a, w in weights.items() if w > 0)
    neg = sum(-w * values[a][rows] for a, w in weights.items() if w < 0)
    return paired_difference(pos, neg, paired_seeds=True)


def label(ci: list[float], margin: float | None) -> str:
    """The plan's words: above or below 0 when the interval excludes 0, "within +-margin" when it lies inside the
    margin, else inconclusive."""
    lo, hi = ci
    if not np.isfinite(lo) or not np.isfinite(hi):
        return "-"
    if lo > 0:
        return "> 0"
    if hi < 0:
        return "< 0"
    if margin is not None and -margin < lo and hi < margin:
        return f"within +-{margin:g}"
    return "inconclusive"


def contrast_rows(results: dict) -> list[dict]:
    """One row per outcome and contrast: mean [95 % CI], the plan's label, each student's mean, and the share of
    the total's mean (the Shapley rows)."""
    out = []
    for name, key, digits in OUTCOMES:
        values = arm_values(results, key)
        if values is None:
            continue
        total = contrast(values, CONTRASTS[0][1])["mean"]
        for cname, weights in CONTRASTS:
            d = contrast(values, weights)
            lo, hi = d["ci95"]
            estimate = f"{d['mean']:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]"
            row = {"outcome": name, "key": key, "contrast": cname, "mean": d["mean"], "ci95": [lo, hi],
                   "episodes": d["episodes"], "estimate": estimate,
                   "label": label([lo, hi], MARGINS.get(key)),
                   "share of total": f"{100 * d['mean'] / total:.0f} %" if "Shapley" in cname and total else ""}
            for k in range(values["RL"].shape[0]):
                row[f"student {k}"] = f"{contrast(values, weights, k)['mean']:+.{digits}f}"
            out.append(row)
    return out


def cell_rows(todo: list[Cell], results: dict, rows: dict[str, list[str]]) -> list[dict]:
    out = []
    for name in [*rows, *(c.name for c in todo)]:
        s = results.get(name)
        if not s:
            continue
        arm = next((a for a, ctrl in ARMS.items() if name.startswith(ctrl)), "?")
        label_ = {"arm": arm, "cell": name if name not in rows else f"{name} (3 students merged)"}
        if "skipped" in s:
            out.append({**label_, "RL reward": f"skipped: {s['skipped']}"})
            continue
        out.append({**label_, "RL reward": med(s["rl_reward"], 3), "RL return": med(s.get("rl_return"), 0),
                    "Initial cost": med(s["initial_cost"]), "Survival": survival(s)})
    return out


def figure(results: dict, path: Path) -> None:
    """Per outcome: the total RL - N, the Shapley parts of the gait and of the forces and the interaction, mean [95 %
    CI], the plan's margin shaded."""
    plt = pyplot()
    keys = [(n, k) for n, k, _ in OUTCOMES if k in ("initial_cost", "rl_reward", "survived")]
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.8))
    picks = (0, 3, 6, 7)
    for ax, (name, key) in zip(np.atleast_1d(axes), keys):
        values = arm_values(results, key)
        if values is None:
            continue
        for i, j in enumerate(picks):
            d = contrast(values, CONTRASTS[j][1])
            m, (lo, hi) = d["mean"], d["ci95"]
            ax.errorbar(i, m, yerr=[[m - lo], [hi - m]], fmt="o", color=f"C{i}", capsize=4)
        if key in MARGINS:
            ax.axhspan(-MARGINS[key], MARGINS[key], color="0.9", zorder=0)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(range(len(picks)), ["RL - N", "gait", "forces", "interaction"])
        ax.set_title(name, fontsize=9)
    fig.suptitle("RL - naive warm start taken apart: the student's gait and footholds vs its forces "
                 "(3 students, paired episodes; grey: the plan's margin)", fontsize=9)
    save(fig, path)


def _flags(p) -> None:
    p.add_argument("--seed-students", type=Path, required=True,
                   help="folder of first-spline_H10_dt0.02_seed<k>/exported/student.pt2, k = 0, 1, 2")


def main() -> None:
    args = parse_args(__doc__, "gait_control", _flags)
    todo, rows = cells(args.seed_students, args.only)
    results = run_cells(todo, args)
    merge_seed_rows(results, rows)
    table = contrast_rows(results)
    cols = ["outcome", "contrast", "estimate", "label", "share of total",
            *(f"student {k}" for k in range(SEED_STUDENTS))]
    write_table(table, cols, args.out / "contrasts", "The RL - naive warm-start differences taken apart, paired on "
                f"the same episodes (mean [95 % CI] over episodes and students; height reference {args.com_height})")
    write_json({"contrasts": table, "margins": MARGINS, **provenance()}, args.out / "contrasts.json", indent=1)
    finish(args, todo, results, cell_rows(todo, results, rows),
           ["arm", "cell", "RL reward", "RL return", "Initial cost", "Survival"],
           "The gait/warm-start control, four arms (M = 10 000, first-spline, H = 10, dt = 0.02 s, F only)", figure,
           "gait_control.png")
    print((args.out / "contrasts.md").read_text())


if __name__ == "__main__":
    run_cli(main)
