"""Students as seeds in the chapter-7.3 experiments: a warm-start row run once per distillation seed's student.

``make distill ... --seed k`` distils one student per training seed k of a setting; :func:`seed_student_cells`
turns every ``rl_warm_start`` cell of a table into one cell per seed's student, and :func:`merge_training_seeds`
merges their summaries into the row, with intervals that resample students and episodes (two levels, as the
distillation tables do).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from dls_quadruped.closed_loop.controller_config import MPC_CONTROLLERS, NEEDS_STUDENT
from dls_quadruped.mpc.config import SamplerConfig
from experiments.warm_start_common import Cell

SEED_STUDENTS = 3
"""Training seeds per setting under ``--seed-students`` (students as seeds)."""
STUDENT_MPC = tuple(c for c in MPC_CONTROLLERS if c in NEEDS_STUDENT)
"""The MPC controllers a student warm-starts: their cells run once per training seed's student."""


def seed_student_path(students: Path, sampler: dict, k: int) -> Path:
    """``<students>/<p>-<F>_H<H>_dt<dt>_seed<k>/exported/student.pt2``: training seed k's student of the setting
    of ``sampler`` (SamplerConfig overrides), as ``make distill ... --seed k`` writes it (cost_gap.py's docstring)."""
    cfg = SamplerConfig(**sampler)
    setting = f"{cfg.encoding_p}-{cfg.encoding_F}_H{cfg.horizon}_dt{cfg.dt:g}_seed{k}"
    return students / setting / "exported" / "student.pt2"


def seed_student_cells(cells: list[Cell], students: Path, only: list[str] | None = None,
                       seeds: int = SEED_STUDENTS) -> tuple[list[Cell], dict[str, list[str]]]:
    """Students as seeds: every cell of a student-warm-started MPC (:data:`STUDENT_MPC`) of one student becomes
    one cell per training seed, ``<name>_seed<k>`` (:func:`seed_student_path`), the others stay. Returns (cells
    to run, {row cell: its seeds' cells}), to merge with :func:`merge_seed_rows` after :func:`run_cells`. The
    students of the cells selected (``only``: those named; None: all) must exist."""
    from dls_quadruped.cli import UserError

    out, rows, missing = [], {}, []
    for c in cells:
        if c.controller not in STUDENT_MPC or c.students or c.student:
            out.append(c)
            continue
        rows[c.name] = []
        for k in range(seeds):
            path = seed_student_path(students, c.sampler, k)
            name = f"{c.name}_seed{k}"
            row = {**c.row, "Controller": f"{c.row['Controller']}, student {k}"} if "Controller" in c.row else c.row
            out.append(replace(c, name=name, student=str(path), row=row))
            rows[c.name].append(name)
            if not path.is_file() and (not only or name in only):
                missing.append(str(path))
    if missing:
        raise UserError(f"--seed-students {students}: no student {missing[0]} (and {len(missing) - 1} more); "
                        "distil them first (experiments/cost_gap.py's docstring)")
    return out, rows


def merge_seed_rows(results: dict[str, dict], rows: dict[str, list[str]]) -> None:
    """Add each row of :func:`seed_student_cells` whose seeds all ran to ``results``, merged
    (:func:`merge_training_seeds`)."""
    for row, names in rows.items():
        if all(n in results for n in names):
            results[row] = merge_training_seeds([results[n] for n in names])


def merge_training_seeds(summaries: list[dict]) -> dict:
    """One table row from the cells of T training seeds (T students of one setting, each run with S sampler
    seeds on the same E episodes): per episode, each student's mean over its sampler seeds, giving (T, E)
    per-episode values whose medians and intervals resample students and episodes (two levels, as the
    distillation tables do); survival pooled over every robot, its interval Wilson's with the episodes as
    the trials; the horizon cost per step the median of the students' medians. A skipped seed skips the row."""
    from dls_quadruped.eval.metrics import episode_summary, wilson_interval

    skipped = [s["skipped"] for s in summaries if "skipped" in s]
    if skipped:
        return {"skipped": skipped[0]}
    episodes = {s["episodes"] for s in summaries}
    if len(episodes) != 1:
        raise ValueError(f"training-seed cells played different episode counts {sorted(episodes)}")
    per_episode = {}
    for key in summaries[0]["per_episode"]:
        per_episode[key] = np.stack([np.nanmean(np.atleast_2d(np.asarray(s["per_episode"][key], dtype=float)), axis=0)
                                     for s in summaries])
    (e,) = episodes
    rate = float(np.mean([s["survival"]["rate"] for s in summaries]))
    out = {"controller": summaries[0]["controller"], "episodes": e, "training_seeds": len(summaries),
           "replicas": sum(s.get("replicas", 1) for s in summaries),
           "survival": {"rate": rate, "ci95": list(wilson_interval(rate * e, e))},
           "per_episode": {k: v.tolist() for k, v in per_episode.items()},
           "seeds": [s.get("cell") for s in summaries],
           "students": [s.get("student") for s in summaries]}  # the same students in two rows: paired by student
    for key, v in per_episode.items():
        if key != "survived":
            out[key] = episode_summary(v)
            out[key]["per_seed_median"] = [s[key]["median"] for s in summaries if key in s]
    if all("horizon_cost" in s for s in summaries):
        out["horizon_cost"] = [{"median": float(np.median([s["horizon_cost"][k]["median"] for s in summaries]))}
                               for k in range(len(summaries[0]["horizon_cost"]))]
    return out
