"""Does the MPC raise base's survival? Flat ground with pushes, preregistered in
``docs/experiments/pushes_plan.md`` (scenario, calibration rule, arms, primary contrast, sample size).

Three stages, each resumable (every cell cached under ``<out>/``):

    python -m experiments.pushes calibrate --episodes 96 --seconds 15   # base alone, validation episodes
    python -m experiments.pushes run --episodes 96 --seconds 15         # the five arms, test episodes
    python -m experiments.pushes report --episodes 96 --seconds 15      # contrasts -> report.md / report.json

(the preregistered size; without ``--episodes``/``--seconds`` the ``--scale`` sizes apply, ``small`` = 4 x 5 s,
a pipeline check).

``--seed-students DIR`` (run and report): the primary contrast with three students: base alone and base's MPC
warm-started by each training seed's student (``<dir>/first-spline_H10_dt0.02_seed<k>/exported/student.pt2``,
k = 0, 1, 2; cells ``base_warm_seed<k>``), merged into the ``base_warm`` row (intervals over episodes and
students, ``experiments/warm_start_seeds.py``); the other arms are not run. The 100-episode run of
``docs/experiments/primary_cells_plan.md``:

    python -m experiments.pushes run --scale thesis --seed 1 --sampler-seeds 1 --push-speed 1.5 \
        --seed-students docs/policies/seed_students --out results/experiments/pushes_thesis

``calibrate`` plays base alone (the RL expert) on ``--episodes`` (96) validation episodes (seed + 1 000 003,
disjoint from the test episodes) for every push speed of ``GRID`` and picks the speed whose survival is
closest to 50 % among those inside [30 %, 70 %]; if none is, it refines between the two grid speeds that
bracket 50 % in steps of 0.125 m/s and applies the rule again. ``run`` plays, on the test episodes (seed),
base alone, the MPC warm-started by base's student, the naive MPC, the MPC warm-started by base and speed
(equal shares) and base's student alone; the MPC arms with ``--sampler-seeds`` (3) noise streams per
episode. ``report`` computes the paired differences (two-level bootstrap over episodes and sampler seeds,
10 000 resamples) and the verdict of the primary contrast under the rules of ``docs/experiments.md``.
"""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.metrics import paired_difference
from dls_quadruped.eval.provenance import provenance
from experiments.rl_common import student_file
from experiments.warm_start_common import REPO, Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_seed_rows
from experiments.warm_start_tables import survival, write_config

GRID = (0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0)
"""[m/s] push speeds of the calibration."""
REFINE_STEP = 0.125
TARGET, BAND = 0.5, (0.3, 0.7)
VALIDATION_OFFSET = 1_000_003
"""Validation episodes are seed + this (``eval --split validation``)."""
DRAWS = 10_000
POLICIES = REPO / "docs" / "policies"
ARMS = ("base_alone", "base_warm", "naive", "base_speed_warm", "student_alone")
PRIMARY = ("base_warm", "base_alone")
SECONDARY = (("naive", "base_alone"), ("base_warm", "naive"), ("base_speed_warm", "base_warm"),
             ("student_alone", "base_alone"))


def choose(rates: dict[float, float]) -> float | None:
    """The push speed whose survival rate is closest to ``TARGET`` among those inside ``BAND`` (the smaller
    speed on a tie), or None if no rate is inside."""
    inside = [(abs(r - TARGET), p) for p, r in rates.items() if BAND[0] <= r <= BAND[1]]
    return min(inside)[1] if inside else None


def refinement(rates: dict[float, float]) -> list[float]:
    """Speeds between the two neighbouring grid speeds whose rates bracket ``TARGET`` (rate falls with speed),
    every ``REFINE_STEP``; empty if no pair brackets it."""
    speeds = sorted(rates)
    for lo, hi in pairwise(speeds):
        if rates[lo] >= TARGET >= rates[hi]:
            n = round((hi - lo) / REFINE_STEP)
            return [round(lo + k * REFINE_STEP, 6) for k in range(1, n)]
    return []


def calibration_cells(speeds) -> list[Cell]:
    return [Cell(f"base_alone_push{p:g}", "rl_baseline", scenario="pushes", push_speed=float(p),
                 row={"push speed [m/s]": f"{p:g}"}) for p in speeds]


def calibrate(args) -> float | None:
    out, seed = args.out, args.seed
    args.out, args.seed = out / "calibration", seed + VALIDATION_OFFSET
    try:
        results = run_cells(calibration_cells(GRID), args)
        rates = {c.push_speed: results[c.name]["survival"]["rate"] for c in calibration_cells(GRID)}
        chosen, refined = choose(rates), []
        if chosen is None:
            refined = refinement(rates)
            results.update(run_cells(calibration_cells(refined), args))
            rates.update({c.push_speed: results[c.name]["survival"]["rate"] for c in calibration_cells(refined)})
            chosen = choose(rates)
        write_config(args, calibration_cells([*GRID, *refined]), {"results": results})
    finally:
        args.out, args.seed = out, seed
    record = {"rule": f"closest to {TARGET:.0%} inside [{BAND[0]:.0%}, {BAND[1]:.0%}]", "grid": list(GRID),
              "refined": refined, "validation_seed": seed + VALIDATION_OFFSET, "episodes": args.episodes,
              "survival": {f"{p:g}": rates[p] for p in sorted(rates)},
              "survival_text": {f"{p:g}": survival(results[f"base_alone_push{p:g}"]) for p in sorted(rates)},
              "chosen_push_speed": chosen}
    write_json({**record, **provenance()}, out / "calibration.json", indent=1)
    for p in sorted(rates):
        print(f"[pushes] push {p:g} m/s: base alone survives {record['survival_text'][f'{p:g}']}")
    print(f"[pushes] chosen push speed: {chosen}")
    return chosen


def arm_cells(push_speed: float, variant: str = "thesis") -> list[Cell]:
    """The five arms; ``variant`` picks the committed experts' students (``--variant``, rl_common.VARIANTS)."""
    common = {"scenario": "pushes", "push_speed": push_speed}
    base, speed = (str(student_file(POLICIES, n, variant)) for n in ("base", "speed"))
    return [Cell("base_alone", "rl_baseline", **common),
            Cell("base_warm", "rl_warm_start", student=base, **common),
            Cell("naive", "naive_warm_start", **common),
            Cell("base_speed_warm", "rl_warm_start", students=(base, speed), **common),
            Cell("student_alone", "student", student=base, **common)]


def seed_arm_cells(push_speed: float, students) -> tuple[list[Cell], dict[str, list[str]]]:
    """``--seed-students``: base alone and ``base_warm`` once per training seed's student (the rows to merge)."""
    from experiments.warm_start_seeds import seed_student_cells

    common = {"scenario": "pushes", "push_speed": push_speed}
    return seed_student_cells([Cell("base_alone", "rl_baseline", **common),
                               Cell("base_warm", "rl_warm_start", **common)], students)


def push_speed_of(args) -> float:
    if args.push_speed is not None:
        return args.push_speed
    path = args.out / "calibration.json"
    if not path.is_file():
        raise SystemExit(f"pushes: no {path}; run `python -m experiments.pushes calibrate` first or give --push-speed")
    chosen = json.loads(path.read_text())["chosen_push_speed"]
    if chosen is None:
        raise SystemExit(f"pushes: the calibration found no push speed inside the band ({path}); see its rates")
    return float(chosen)


def verdict(ci: list[float]) -> str:
    """The plan's rule (pushes_plan.md) for a claimed increase: reproduced above 0, contradicted below. It tests
    the direction only; the verdict table (``experiments/verdicts.py``) also tests the thesis's size."""
    if ci[0] > 0:
        return "reproduced"
    if ci[1] < 0:
        return "contradicted"
    return "inconclusive"


def contrast(results: dict, a: str, b: str, key: str) -> dict:
    pa, pb = results[a]["per_episode"][key], results[b]["per_episode"][key]
    return paired_difference(np.array(pa), np.array(pb), draws=DRAWS, seed=0)


def report(args) -> dict:
    p = push_speed_of(args)
    cells, arms = (arm_cells(p, args.variant), ARMS)
    if args.seed_students:
        cells, seeded = seed_arm_cells(p, args.seed_students)
        arms = PRIMARY[::-1]
    results = run_cells(cells, args)
    if args.seed_students:
        merge_seed_rows(results, seeded)
    missing = [a for a in arms if a not in results or "skipped" in results[a]]
    if missing:
        raise SystemExit(f"pushes: arms not run yet: {missing}; run `python -m experiments.pushes run` first")
    rows = {a: {"survival": survival(results[a]), "rate": results[a]["survival"]["rate"],
                "return_per_episode_median": results[a]["rl_return"]["median"]} for a in arms}
    pairs = [PRIMARY, *(SECONDARY if not args.seed_students else ())]
    diffs = {f"{a} - {b}": {"survived": contrast(results, a, b, "survived"),
                            "rl_return": contrast(results, a, b, "rl_return")} for a, b in pairs}
    primary = diffs[f"{PRIMARY[0]} - {PRIMARY[1]}"]["survived"]
    students = len(seeded["base_warm"]) if args.seed_students else 1
    out = {"push_speed": p, "episodes": args.episodes, "sampler_seeds": args.sampler_seeds, "seed": args.seed,
           "students": students,
           "draws": DRAWS, "arms": rows, "contrasts": diffs,
           "primary": {"contrast": f"{PRIMARY[0]} - {PRIMARY[1]}, survival", **primary,
                       "verdict": verdict(primary["ci95"])},
           "wall_s": {c.name: results[c.name].get("seconds_wall") for c in cells if c.name in results}}
    write_json({**out, **provenance()}, args.out / "report.json", indent=1)
    title = (f"# MPC survival under pushes ({args.episodes} test episodes x {args.sampler_seeds} sampler seeds"
             f"{f' x {students} students' if students > 1 else ''}, push speed {p:g} m/s)")
    lines = [title, "", "| arm | survival [95 % CI] | return per episode (median) |", "|---|---|---|"]
    lines += [f"| {a} | {r['survival']} | {r['return_per_episode_median']:.1f} |" for a, r in rows.items()]
    lines += ["", "| contrast | survival difference [95 % CI] | return difference [95 % CI] |", "|---|---|---|"]
    for name, d in diffs.items():
        s, r = d["survived"], d["rl_return"]
        lines.append(f"| {name} | {s['mean']:+.3f} [{s['ci95'][0]:+.3f}, {s['ci95'][1]:+.3f}] | "
                     f"{r['mean']:+.1f} [{r['ci95'][0]:+.1f}, {r['ci95'][1]:+.1f}] |")
    lines += ["", (f"Primary ({out['primary']['contrast']}): {primary['mean']:+.3f} [{primary['ci95'][0]:+.3f}, "
                   f"{primary['ci95'][1]:+.3f}]: **{out['primary']['verdict']}** by the plan's rule (the direction; "
                   "the verdict table of docs/experiments.md also tests the thesis's size).")]
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    write_config(args, cells, {"results": results, "push_speed": p})
    return out


def main() -> None:
    def extra(parser):
        parser.add_argument("stage", choices=("calibrate", "run", "report"))
        parser.add_argument("--push-speed", type=float, default=None,
                            help="run/report: this push speed [m/s] instead of the calibration's")
        parser.add_argument("--seed-students", type=Path, default=None,
                            help="run/report: the primary contrast only, base's MPC warm-started by each student "
                                 "<dir>/first-spline_H10_dt0.02_seed<k>/exported/student.pt2 (k = 0, 1, 2), merged")

    args = parse_args(__doc__, "pushes", extra)
    if args.stage == "calibrate":
        calibrate(args)
    elif args.stage == "run":
        p = push_speed_of(args)
        run_cells(seed_arm_cells(p, args.seed_students)[0] if args.seed_students else arm_cells(p, args.variant), args)
    else:
        report(args)


if __name__ == "__main__":
    main()
