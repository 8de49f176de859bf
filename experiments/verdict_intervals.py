"""Our number for each claim of the verdict table, with its 95 % interval, and the rule that judges it.

An :class:`Interval` is read from a committed result file under ``docs/experiments/<experiment>/`` (a
``value [lo, hi]`` cell of a table, a row of a 7.1 figure's ``paired.csv``) or recomputed from the per-episode
values with the experiments' own bootstrap (``distill_metrics.sp_difference``, ``eval.metrics.paired_difference``:
seed 0, 2 000 resamples); :func:`verdict` applies the rules written at the top of ``docs/experiments.md``.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "experiments"
"""The committed result files, one folder per experiment."""


@dataclass(frozen=True)
class Interval:
    """A number with its 95 % interval, and the text it is quoted as (the result file's own where it has one)."""
    value: float
    lo: float
    hi: float
    text: str


def verdict(iv: Interval | None, direction: int = 0, thesis: float | None = None, margin: float | None = None) -> str:
    """The rule of ``docs/experiments.md`` for one claim.

    Args:
        iv: our estimate, oriented as the claim (a difference "A - B" for "A > B"); None: no interval.
        direction: +1 the thesis claims iv > 0, -1 it claims iv < 0, 0 the claim is a value (``thesis``).
        thesis, margin: the thesis's value and the margin around it; with ``direction`` they test its size.

    Returns "reproduced", "contradicted" or "inconclusive":
        difference: reproduced if the interval excludes 0 in the thesis's direction (and, when a size is
        given, does not miss thesis +- margin); contradicted if it excludes 0 the other way or misses
        thesis +- margin; else inconclusive.
        value: reproduced if the interval lies inside thesis +- margin, contradicted if outside, else inconclusive.
    """
    if iv is None:
        return "inconclusive"
    missed = thesis is not None and margin is not None and (iv.hi < thesis - margin or iv.lo > thesis + margin)
    if direction == 0:
        if thesis is None or margin is None:
            raise ValueError("a value claim needs the thesis's value and a margin")
        if missed:
            return "contradicted"
        return "reproduced" if thesis - margin <= iv.lo and iv.hi <= thesis + margin else "inconclusive"
    near, far = sorted((direction * iv.lo, direction * iv.hi))  # the interval, turned so the claim is "> 0"
    if near > 0:
        return "contradicted" if missed else "reproduced"
    return "contradicted" if far < 0 or missed else "inconclusive"


def apart(a: Interval, b: Interval) -> Interval:
    """a - b from two unpaired intervals, conservatively: [a.lo - b.hi, a.hi - b.lo] (it excludes 0 only when
    the two intervals do not overlap); quoted as the two intervals."""
    return Interval(a.value - b.value, a.lo - b.hi, a.hi - b.lo, f"{a.text} vs {b.text}")


# ---------------------------------------------------------------------------------------------------------------
# Reading the result files


@cache
def _json(folder: str, name: str = "results.json") -> dict:
    return json.loads((RESULTS / folder / name).read_text())


@cache
def _csv(folder: str, name: str = "table.csv") -> list[dict]:
    with open(RESULTS / folder / name, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


NUMBER = r"[-+−]?\d+(?:\.\d+)?"
CELL = re.compile(rf"^\s*(?:[<>])?({NUMBER})\s*%?\s*\[({NUMBER}),\s*({NUMBER})\]")


def parse(text: str) -> Interval:
    """'1.61 [1.56, 1.69]', '97.7 % [91.8, 100.1]', '+9.2 [-6.0, +26.7] ...' -> Interval (the text as given)."""
    m = CELL.match(text)
    if m is None:
        raise ValueError(f"no 'value [lo, hi]' in {text!r}")
    v, lo, hi = (float(x.replace("−", "-")) for x in m.groups())
    return Interval(v, lo, hi, text.split(" (")[0].strip())


def cell(folder: str, column: str, name: str = "table.csv", **match: str) -> Interval:
    """A 'value [lo, hi]' cell of a result table: the row whose columns equal ``match``."""
    rows = [r for r in _csv(folder, name) if all(r.get(k) == v for k, v in match.items())]
    if len(rows) != 1:
        raise KeyError(f"{folder}/{name}: {len(rows)} rows match {match}")
    return parse(rows[0][column])


def paired_csv(folder: str, policy: str, metric: str) -> Interval:
    """A row of a 7.1 figure's ``paired.csv`` (expert minus base on the same episodes), as the file prints it."""
    (row,) = [r for r in _csv(folder, "paired.csv") if r["policy"] == policy and r["metric"] == metric]
    lo, hi = (float(x) for x in row["95 % CI"].strip("[]").split(","))
    return Interval(float(row["mean difference"]), lo, hi, f"{row['mean difference']} {row['95 % CI']}")


def pushes_primary(folder: str = "pushes") -> Interval:
    """The preregistered primary contrast of ``experiments/pushes.py`` (``report.json``), survival fraction."""
    d = _json(folder, "report.json")["primary"]
    return Interval(d["mean"], *d["ci95"], _fmt(d["mean"], *d["ci95"], 3))


def pushes_reading(folder: str) -> str:
    """The verdict of a pushes run's primary contrast if the thesis's "38 %" is relative to base alone's survival
    (+0.38 x base alone's rate, the survival margin around it): the thesis does not say which it is."""
    d = _json(folder, "report.json")
    rate, p = d["arms"]["base_alone"]["rate"], d["primary"]
    size = 0.38 * rate
    rel = verdict(Interval(p["mean"], *p["ci95"], ""), +1, size, 0.10)
    return (f"'38 %' may be relative (the thesis does not say): +38 % of base alone's {100 * rate:.0f} % is "
            f"+{size:.2f} ± 0.10, {rel} on that reading")


def equivalence(iv: Interval, margin: float) -> str:
    """A no-difference reading of ``iv`` with an equivalence margin stated before the run: "equivalent" when the
    interval lies inside +- margin, "different" when it excludes 0, else "inconclusive"."""
    if -margin <= iv.lo and iv.hi <= margin:
        return "equivalent"
    return "different" if iv.lo > 0 or iv.hi < 0 else "inconclusive"


def sweep_large_data() -> str:
    """The Table 11 sweep's cells at 100 000 and 400 000 datapoints under its plan's +-5-point equivalence margin."""
    cells = {(n, c, e): sweep_gap(e, f"naive_{c}_{n}", f"dagger_{c}_{n}", folder=f"table11_sweep_medium_{n}")
             for n in ("100k", "400k") for c in ("today", "narrow") for e in ("plain", "disturbed")}
    by = {k: equivalence(iv, 5.0) for k, iv in cells.items()}
    eq = [f"{e}, {c}, {n[:3]} 000: {cells[n, c, e].text}" for (n, c, e), v in by.items() if v == "equivalent"]
    worst = max((k for k, v in by.items() if v == "inconclusive"), key=lambda k: cells[k].hi - cells[k].lo)
    return (f"at 100 000 and 400 000 datapoints {sum(v == 'different' for v in by.values())} of {len(by)} cells "
            f"exclude 0, {len(eq)} is equivalent within the plan's ±5 points ({'; '.join(eq)}), "
            f"{sum(v == 'inconclusive' for v in by.values())} cross the margin: inconclusive (widest: "
            f"{worst[2]}, {worst[1]}, {worst[0][:3]} 000: {cells[worst].text})")


def _fmt(v: float, lo: float, hi: float, digits: int, unit: str = "") -> str:
    return f"{v:+.{digits}f}{unit} [{lo:+.{digits}f}, {hi:+.{digits}f}]"


def sp_gap(folder: str, a: str, b: str, snapshot: int = -1) -> Interval:
    """SP(a) - SP(b) in points on the same episodes (``distill_metrics.sp_difference``: each run's seeds
    resampled on their own, the episodes jointly), from ``results.json``'s returns."""
    from dls_quadruped.learning.distill_metrics import sp_difference

    res = _json(folder)["returns"]

    def r_0(run: str) -> np.ndarray:
        untrained = res["untrained"]
        if len(untrained) == 1:
            return np.asarray(next(iter(untrained.values())))
        _, enc, _, horizon = run.split("_")  # "33_spline-discrete_dt0.04_H15"
        p, f = enc.split("-")
        (key,) = [k for k in untrained if k.startswith(f"{p} {f} {horizon[1:]} ")]
        return np.asarray(untrained[key])

    d = sp_difference(np.asarray(res[a][snapshot]), np.asarray(res[b][snapshot]), np.asarray(res["expert"]),
                      r_0(a), r_0(b))
    v, (lo, hi) = 100 * d["difference"], (100 * x for x in d["ci95"])
    return Interval(v, lo, hi, _fmt(v, lo, hi, 1))


def sweep_gap(evaluation: str, a: str, b: str, folder: str = "table11_sweep_medium") -> Interval:
    """SP(a) - SP(b) in points from ``experiments/table11_sweep.py``'s results (one untrained student, the
    returns of each evaluation, ``plain`` or ``disturbed``, under its own key)."""
    from dls_quadruped.learning.distill_metrics import sp_difference

    res = _json(folder)[evaluation]["returns"]
    (r_0,) = res["untrained"].values()
    d = sp_difference(np.asarray(res[a][-1]), np.asarray(res[b][-1]), np.asarray(res["expert"]), np.asarray(r_0),
                      np.asarray(r_0))
    v, (lo, hi) = 100 * d["difference"], (100 * x for x in d["ci95"])
    return Interval(v, lo, hi, _fmt(v, lo, hi, 1))


def expert_gap(folder: str, scenario: str, a: str, b: str, key: str = "survived") -> Interval:
    """Expert ``a`` minus expert ``b`` on the same episodes, from the per-episode files ``<folder>/<task>/
    <scenario>.json`` of a 7.1 figure (``eval.compare.per_episode_values``; ``key`` as there)."""
    from dls_quadruped.eval.compare import per_episode_values
    from dls_quadruped.eval.metrics import paired_difference

    x, y = (per_episode_values(_json(f"{folder}/{t}", f"{scenario}.json"), key) for t in (a, b))
    d = paired_difference(x, y)
    return Interval(d["mean"], *d["ci95"], f"{d['mean']:+.4f} [{d['ci95'][0]:+.4f}, {d['ci95'][1]:+.4f}]")


def survival_gap(folder: str, scenario: str) -> Interval:
    """Climb minus rough survival on the same episodes (the 7.1 figures pair every expert with base only)."""
    return expert_gap(folder, scenario, "climb", "rough")


def _per_episode(folder: str, name: str, key: str) -> np.ndarray:
    return np.asarray(_json(folder)[name]["per_episode"][key], dtype=float)


def gap(folder: str, a: str, b: str | tuple[str, str], key: str = "initial_cost", scale: float = 1.0,
        digits: int = 1, relative: bool = False) -> Interval:
    """Closed-loop cells a - b on the same episodes (``eval.metrics.paired_difference``: mean over episodes of
    the seed-averaged difference; ``relative``: sum_e d_e / sum_e b_e in %). ``b`` a pair: their mean."""
    from dls_quadruped.eval.metrics import paired_difference

    if isinstance(b, tuple):  # per episode, the mean of two cells' seed-averaged values
        ref = np.nanmean([np.nanmean(np.atleast_2d(_per_episode(folder, c, key)), 0) for c in b], 0)
    else:
        ref = _per_episode(folder, b, key)
    d = paired_difference(_per_episode(folder, a, key), ref)
    if relative:
        v, lo, hi = (100 * x for x in (d["relative"], *d["relative_ci95"]))
        return Interval(v, lo, hi, _fmt(v, lo, hi, 1, " %"))
    v, lo, hi = (scale * x for x in (d["mean"], *d["ci95"]))
    return Interval(v, lo, hi, _fmt(v, lo, hi, digits))


def relative_gap_difference(folder: str, a: tuple[str, str], b: tuple[str, str], key: str = "initial_cost",
                            draws: int = 2000, seed: int = 0,
                            paired_seeds: tuple[bool, bool] = (False, False)) -> Interval:
    """(Δ_a - Δ_b) in points of %, Δ = sum_e (x_e - ref_e) / sum_e ref_e (Table 16's Δ) of two (cell, reference)
    pairs on the same episodes; the interval resamples the episodes jointly for the four cells and each cell's
    seeds on its own (the two-level bootstrap of ``paired_difference``), or, for a pair marked in
    ``paired_seeds`` (rows merged from the same students), its two cells' seeds together."""
    cells = [_per_episode(folder, c, key) for c in (*a, *b)]
    rng = np.random.default_rng(seed)
    e = cells[0].shape[1]
    cols = rng.integers(0, e, size=(draws, 1, e))

    def rel(x, ref):  # (..., S, E) -> (...)
        xm, rm = np.nanmean(x, axis=-2), np.nanmean(ref, axis=-2)
        return np.nansum(xm - rm, axis=-1) / np.nansum(rm, axis=-1)

    def boot(x, ref, joint):
        rows = rng.integers(0, x.shape[0], size=(draws, x.shape[0], 1))
        if joint and x.shape[0] != ref.shape[0]:
            raise ValueError(f"paired seeds need the same seeds in both cells, got {x.shape[0]} and {ref.shape[0]}")
        ref_rows = rows if joint else rng.integers(0, ref.shape[0], size=(draws, ref.shape[0], 1))
        return x[rows, cols], ref[ref_rows, cols]

    v = 100 * (rel(cells[0], cells[1]) - rel(cells[2], cells[3]))
    bs = 100 * (rel(*boot(*cells[:2], paired_seeds[0])) - rel(*boot(*cells[2:], paired_seeds[1])))
    lo, hi = np.percentile(bs[np.isfinite(bs)], [2.5, 97.5])
    return Interval(float(v), float(lo), float(hi), _fmt(float(v), float(lo), float(hi), 1, " points"))


EXPERT_SEED_TABLE14 = {"expert seed 1": "expert_seeds/table14_T1", "expert seed 2": "expert_seeds/table14_T2"}
"""Table 14's first-spline cells with the Table 6 experts of training seeds 1 and 2 and one student each
(``docs/experiments/expert_seeds_plan.md`` part 2); seed 0 is the table's own run."""


@cache  # the row's reason and its note both ask: the bootstraps run once
def _across_expert_seeds(folder: str, a: str, b: str, key: str, direction: int, digits: int) -> tuple[bool, str]:
    """(whether every expert seed gives seed 0's verdict, the seeds' intervals as text)."""
    own = verdict(gap(folder, a, b, key, digits=digits), direction)
    seeds = _seed_verdicts("", a, b, key, direction, digits)
    return all(v == own for _, v in seeds), ", ".join(text for text, _ in seeds)


def _seed_verdicts(suffix: str, a: str, b: str, key: str, direction: int, digits: int) -> list[tuple[str, str]]:
    """("<seed> <interval> (<verdict>)", verdict) of each expert seed's cells (``EXPERT_SEED_TABLE14`` + ``suffix``)."""
    out = []
    for name, f in EXPERT_SEED_TABLE14.items():
        iv = gap(f + suffix, a, b, key, digits=digits)
        v = verdict(iv, direction)
        out.append((f"{name} {iv.text} ({v})", v))
    return out


def expert_seeds_why(folder: str, a: str, b: str, key: str, direction: int, digits: int = 1) -> str:
    """A verdict row's reason when its label holds for expert seed 0 only (the plan's rule): "" when it holds."""
    same, text = _across_expert_seeds(folder, a, b, key, direction, digits)
    return "" if same else f"expert seed 0 only: {text}, one student each"


def expert_seeds_at_height(a: str, b: str, key: str, direction: int, digits: int = 1) -> str:
    """The same contrast in the plan amendment's cells, every reference at each seed's own walking height
    (``expert_seeds/table14_T<k>_height``), as text with each seed's verdict."""
    seeds = _seed_verdicts("_height", a, b, key, direction, digits)
    return "at each seed's own walking height: " + ", ".join(text for text, _ in seeds)


def floor_why(folder: str, name: str, alone: str, warm: str) -> str:
    """A survival row's reason when the task is at its floor: the policy alone's and the warm start's survival, as
    the result table ``folder/name`` prints them (rows named in its "Warm start" column)."""
    rows = {r["Warm start"]: r["survival"].split(" (n=")[0] for r in _csv(folder, name)}
    return f"{alone} survives {rows[alone]}, the warm start {rows[warm]}: the task's floor, no room to rise"


def expert_seeds_note(folder: str, a: str, b: str, key: str, direction: int, digits: int = 1) -> str:
    """A verdict row's caveat when its label holds across the three expert seeds: "" when it does not."""
    same, text = _across_expert_seeds(folder, a, b, key, direction, digits)
    return f"holds across three expert seeds ({text})" if same else ""
