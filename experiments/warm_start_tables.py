"""The tables of the chapter-7.3 experiments: cells summarised as the thesis does, written with the run's config.

Cells are compared on the same scheduled episodes: :func:`med` quotes a cell's median over episodes and seeds,
:func:`paired` the paired difference of two cells, :func:`survival` a survival rate with Wilson's interval;
:func:`tabulate` lays the cells out in rows and :func:`finish` writes the table, ``results.json``, the figure
and ``config.json``.
"""

from __future__ import annotations

import argparse

import numpy as np

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from experiments.output import write_table
from experiments.warm_start_common import COMMITTED_STUDENT, Cell


def med(m: dict | None, digits: int = 1) -> str:
    """'median [95 % CI]' of an ``episode_summary`` dict (median over episodes and seeds of each
    episode's median; the interval of that median over episodes and seeds)."""
    if not m or m.get("n", 0) == 0 or m.get("median") is None or not np.isfinite(m["median"]):
        return "-"
    lo, hi = m.get("ci95", [m.get("q1"), m.get("q3")])
    return f"{m['median']:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def paired(results: dict, a: str, b: str, key: str, digits: int = 1, relative: bool = False,
           median: bool = False) -> str:
    """Paired difference of cells ``a`` - ``b`` on the same episodes: 'mean [95 % CI]' (or the relative
    difference sum d / sum b in %), '-' if either cell is missing or was skipped. Two rows merged from the same
    students (:func:`merge_training_seeds`' ``students``) are paired by student too. ``median``: the median over
    episodes of the paired differences instead of their mean."""
    from dls_quadruped.eval.metrics import paired_difference

    sa, sb = results.get(a) or {}, results.get(b) or {}
    if any("per_episode" not in s or key not in s["per_episode"] for s in (sa, sb)):
        return "-"
    same = sa.get("students") is not None and sa.get("students") == sb.get("students")
    d = paired_difference(np.array(sa["per_episode"][key]), np.array(sb["per_episode"][key]), paired_seeds=same)
    if relative:
        return f"{100 * d['relative']:+.1f} % [{100 * d['relative_ci95'][0]:+.1f}, {100 * d['relative_ci95'][1]:+.1f}]"
    v, (lo, hi) = (d["median"], d["median_ci95"]) if median else (d["mean"], d["ci95"])
    return f"{v:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]"


def survival(s: dict) -> str:
    """'rate [95 % CI] (n=episodes x seeds)': with seeds, Wilson's interval with the episodes as the trials
    (the copies of one episode are not independent), else Wilson's over the episodes."""
    from dls_quadruped.eval.metrics import wilson_interval

    v = s["survival"]
    lo, hi = wilson_interval(v["rate"] * s["episodes"], s["episodes"]) if s.get("replicas", 1) > 1 else v["ci95"]
    n = f"{s['episodes']}x{s['replicas']}" if s.get("replicas", 1) > 1 else f"{v['n']}"
    return f"{100 * v['rate']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] (n={n})"


def write_config(args: argparse.Namespace, cells: list[Cell], extra: dict | None = None) -> None:
    from dls_quadruped.bench.machine import cpu_model

    wall = sum(r.get("seconds_wall", 0.0) for r in (extra or {}).pop("results", {}).values())
    write_json({"scale": args.scale, "episodes_per_cell": args.episodes, "seconds": args.seconds, "seed": args.seed,
                "sampler_seeds": args.sampler_seeds, "cells_wall_s": round(wall, 1),
                "threads": args.threads, **provenance(), "cpu": cpu_model(), "policy": str(args.policy),
                "variant": getattr(args, "variant", "thesis"), "com_height": getattr(args, "com_height", None),
                "committed_student": str(getattr(args, "committed_student", COMMITTED_STUDENT)),
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
                f"{args.seconds:g} s per cell, {args.sampler_seeds} sampler seeds per MPC episode; median over "
                f"episodes and seeds of each episode's median [95 % CI]; rollout cost: state-only, full J beside it)")
    write_json(results, args.out / "results.json", indent=1)
    figure(results, args.out / figure_name)
    write_config(args, cells, {"results": results})
    print((args.out / "table.md").read_text())
