"""Shared machinery of the chapter-7.3 experiments (Tables 14-17, Fig. 28): closed-loop cells.

A *cell* is one controller (``rl_warm_start``, ``naive_warm_start``, ``rl_baseline``) with one MPC
setting, run for a batch of episodes in parallel (``dls_quadruped.closed_loop``) on the thesis's simple
task or a fixed forward speed, and summarised as the thesis does (medians with first and third
quartiles, 7.3.1; survival with a Wilson interval). Every cell is cached in
``<out>/cells/<name>.json``: an interrupted script continues with the cells it has not finished.

Scales (episodes x seconds per cell): ``small`` 4 x 5 s (minutes on 2 cores; medians of ~1 000
pooled steps, a pipeline check more than a measurement), ``medium`` 16 x 15 s, ``thesis``
100 x 15 s (7.3.1: 100 trajectories per configuration).

Students: ``rl_warm_start`` needs a student distilled for the cell's encoding, horizon and dt: the
committed ``docs/policies/base_student_first_spline_h10.pt`` for first-spline, H = 10, dt = 0.02 s,
otherwise ``<students>/<p>-<F>_H<H>_dt<dt>/exported/student.pt`` (``--students``, default
``results/experiments/students``), made by ``experiments/make_students.sh`` (``make distill`` per
encoding). A cell whose student is missing is skipped with a note in the table (never silently
replaced by another).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import json

import numpy as np
import torch

from dls_quadruped.closed_loop.__main__ import commands, run_controllers
from dls_quadruped.closed_loop.controllers import ControllerConfig
from dls_quadruped.closed_loop.metrics import summarize
from dls_quadruped.core.json_io import write_json
from dls_quadruped.mpc.config import SamplerConfig
from experiments.distill_common import write_table
from experiments.rl_common import pyplot, save  # noqa: F401 (the tables' plot helpers, shared with the 7.1 scripts)

SCALES = {"small": {"episodes": 4, "seconds": 5.0}, "medium": {"episodes": 16, "seconds": 15.0},
          "thesis": {"episodes": 100, "seconds": 15.0}}
POLICY = REPO / "docs" / "policies" / "base_actor.pt"
COMMITTED_STUDENT = REPO / "docs" / "policies" / "base_student_first_spline_h10.pt"


@dataclass(frozen=True)
class Cell:
    """One table cell: a controller and its MPC settings on one command set."""

    name: str
    controller: str
    sampler: dict = field(default_factory=dict)   # SamplerConfig overrides (num_samples, horizon, dt, encoding_*)
    optimise: tuple[str, ...] = ("F",)
    vx: float | None = None                      # fixed forward speed, else the simple task
    naive_share: float = 0.0                      # rl_warm_start: share of samples around the previous solution
    row: dict = field(default_factory=dict)       # table columns


def parse_args(description: str, name: str) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scale", choices=sorted(SCALES), default="small")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / name)
    p.add_argument("--students", type=Path, default=REPO / "results" / "experiments" / "students",
                   help="folder of students <p>-<F>_H<H>_dt<dt>/exported/student.pt")
    p.add_argument("--policy", type=Path, default=POLICY)
    p.add_argument("--episodes", type=int, default=None, help="override the scale's episodes per cell (even)")
    p.add_argument("--seconds", type=float, default=None, help="override the scale's episode length [s]")
    p.add_argument("--threads", type=int, default=1, help="torch / MPC kernel threads")
    p.add_argument("--num-workers", type=int, default=0, help="simulator processes (0: in-process, the closed loop's fastest)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", nargs="*", default=None, help="run only these cells")
    args = p.parse_args()
    args.episodes = args.episodes or SCALES[args.scale]["episodes"]
    args.seconds = args.seconds or SCALES[args.scale]["seconds"]
    return args


def student_path(students: Path, p: str, F: str, horizon: int, dt: float) -> Path | None:
    """The student for an encoding, or None. The thesis's default configuration (first-spline, H = 10,
    dt = 0.02 s) uses the committed student (``docs/policies``, the demo's), so every table shares it."""
    if (p, F, horizon, dt) == ("first", "spline", 10, 0.02) and COMMITTED_STUDENT.is_file():
        return COMMITTED_STUDENT
    path = students / f"{p}-{F}_H{horizon}_dt{dt:g}" / "exported" / "student.pt"
    return path if path.is_file() else None


def run_cells(cells: list[Cell], args: argparse.Namespace) -> dict[str, dict]:
    """Run (or load from the cache) every cell; {name: summary or {"skipped": why}}."""
    torch.set_num_threads(args.threads)
    out: dict[str, dict] = {}
    (args.out / "cells").mkdir(parents=True, exist_ok=True)
    for k, cell in enumerate(cells):
        if args.only and cell.name not in args.only:
            continue
        path = args.out / "cells" / f"{cell.name}.json"
        if path.is_file():
            out[cell.name] = json.loads(path.read_text())
            continue
        sampler = SamplerConfig(**cell.sampler)
        student = None
        if cell.controller == "rl_warm_start":
            student = student_path(args.students, sampler.encoding_p, sampler.encoding_F, sampler.horizon, sampler.dt)
            if student is None:
                out[cell.name] = {"skipped": f"no student {sampler.encoding_p}-{sampler.encoding_F}_H{sampler.horizon}"
                                             f"_dt{sampler.dt:g} under {args.students}"}
                print(f"[{args.out.name}] {cell.name}: skipped ({out[cell.name]['skipped']})", flush=True)
                continue
        cfg = ControllerConfig(cell.controller, policy=args.policy, student=student, sampler=sampler,
                               optimise=cell.optimise, naive_share=cell.naive_share, seed=args.seed)
        t0 = time.monotonic()
        traces = run_controllers([cfg], commands(args.episodes, args.seed, cell.vx), args.seconds, args.seed,
                                 args.num_workers)[cell.controller]
        summary = summarize(traces)
        summary.update({"cell": cell.name, "student": str(student) if student else None, "row": cell.row,
                        "sampler": cell.sampler, "optimise": list(cell.optimise), "vx": cell.vx,
                        "naive_share": cell.naive_share,
                        "seconds_wall": time.monotonic() - t0})
        write_json(summary, path, indent=1)
        out[cell.name] = summary
        s = summary
        print(f"[{args.out.name}] {k + 1}/{len(cells)} {cell.name}: reward {s['rl_reward']['median']:.3f}, "
              f"initial cost {s['initial_cost']['median']:.1f}, survival {s['survival']['rate']:.2f}, "
              f"{summary['seconds_wall']:.0f} s", flush=True)
    return out


def med(m: dict | None, digits: int = 1) -> str:
    """'median [q1, q3]' of a median_iqr dict."""
    if not m or m.get("n", 0) == 0 or m.get("median") is None or not np.isfinite(m["median"]):
        return "-"
    return f"{m['median']:.{digits}f} [{m['q1']:.{digits}f}, {m['q3']:.{digits}f}]"


def survival(s: dict) -> str:
    v = s["survival"]
    return f"{100 * v['rate']:.0f} % [{100 * v['ci95'][0]:.0f}, {100 * v['ci95'][1]:.0f}] (n={v['n']})"


def write_config(args: argparse.Namespace, cells: list[Cell], extra: dict | None = None) -> None:
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True,
                                check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    from dls_quadruped.bench.machine import cpu_model

    write_json({"scale": args.scale, "episodes_per_cell": args.episodes, "seconds": args.seconds, "seed": args.seed,
                "threads": args.threads, "git_commit": commit, "cpu": cpu_model(), "policy": str(args.policy),
                "students": str(args.students), "cells": [c.name for c in cells], **(extra or {})},
               args.out / "config.json")


def tabulate(cells: list[Cell], results: dict[str, dict], columns, thesis) -> list[dict]:
    """One row per cell that ran or was skipped: the cell's labels, ``columns(cell, summary)`` (or the
    reason it was skipped) and ``thesis(cell)``, the thesis's numbers to print beside ours."""
    rows = []
    for c in cells:
        s = results.get(c.name)
        if s is None:
            continue
        row = dict(c.row)
        row.update({"RL reward": f"skipped: {s['skipped']}"} if "skipped" in s else columns(c, s))
        row.update(thesis(c))
        rows.append(row)
    return rows


def finish(args: argparse.Namespace, cells: list[Cell], results: dict, rows: list[dict], columns: list[str],
           title: str, figure, figure_name: str) -> None:
    """Write table.md/.csv (titled with the scale), results.json, the figure and config.json; print the table."""
    write_table(rows, columns, args.out / "table", f"{title} ({args.scale}: {args.episodes} episodes x "
                f"{args.seconds:g} s per cell; median [q1, q3] over every step)")
    write_json(results, args.out / "results.json", indent=1)
    figure(results, args.out / figure_name)
    write_config(args, cells)
    print((args.out / "table.md").read_text())
