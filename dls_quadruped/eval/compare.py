"""Paired comparison of two policies evaluated on the same scheduled episodes.

    python -m dls_quadruped.eval --policy new.pt --scenario simple --episodes 256 --out results/eval/new
    python -m dls_quadruped.eval --policy old.pt --scenario simple --episodes 256 --out results/eval/old
    python -m dls_quadruped.eval.compare results/eval/new/simple.json results/eval/old/simple.json [--out d.json]

With the same ``--seed`` and ``--episodes`` both evaluations draw every episode's command, pushes and
noise from one schedule (``envs/schedule.py``), so episode e is the same episode for both policies. For
each per-episode metric both results record (survival, mean reward per step, episode length, cost of
transport) this prints the mean over episodes of (A - B) with its 95 % bootstrap interval over episodes
(``eval.metrics.paired_difference``), and A's and B's own means. An interval that excludes 0 says the
difference is more than the episodes' spread; it says nothing about another seed's training run.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.metrics import paired_difference

PAIRED_METRICS = {"survived": "survival [share]", "reward": "mean reward per step", "length_s": "episode length [s]",
                  "cot": "cost of transport"}
"""Per-episode values compared between two evaluations, when the scenario records them."""


def per_episode_values(result: dict, key: str) -> np.ndarray | None:
    """The per-episode values of ``key`` (``"survived"``: 1 - fell) as floats (null -> NaN); None if not recorded."""
    pe = result.get("per_episode") or {}
    if key == "survived":
        return None if "fell" not in pe else 1.0 - np.array(pe["fell"], dtype=float)
    return None if key not in pe else np.array([np.nan if v is None else v for v in pe[key]], dtype=float)


def paired_vs(results: dict[str, dict], reference: str = "base") -> list[dict]:
    """Every result minus ``results[reference]`` on the same scheduled episodes: for each per-episode metric
    both recorded, the mean of the per-episode differences with its 95 % bootstrap interval over episodes.
    Results whose episodes differ (another command list) are not paired and left out."""
    ref = results.get(reference)
    if not ref or not ref.get("per_episode"):
        return []
    rows = []
    for name, res in results.items():
        pe = res.get("per_episode")
        if name == reference or not pe or pe.get("command") != ref["per_episode"].get("command"):
            continue
        for key, label in PAIRED_METRICS.items():
            a, b = per_episode_values(res, key), per_episode_values(ref, key)
            if a is None or b is None or a.shape != b.shape or a.ndim != 1:
                continue
            d = paired_difference(a, b)
            rows.append({"policy": f"{name} - {reference}", "metric": label, "mean difference": round(d["mean"], 4),
                         "95 % CI": f"[{d['ci95'][0]:.4f}, {d['ci95'][1]:.4f}]", "episodes": d["episodes"]})
    return rows


def check_paired(a: dict, b: dict, names: tuple[str, str]) -> None:
    """Raise UserError naming the first thing that makes ``a`` and ``b`` not the same episodes."""
    for key in ("scenario", "seed", "episodes", "episode_length_s"):
        if a.get(key) != b.get(key):
            raise UserError(f"{names[0]} and {names[1]} are not the same episodes: {key} {a.get(key)!r} vs "
                             f"{b.get(key)!r} (evaluate both with the same --scenario, --seed, --episodes and "
                             "--episode-length-s)")
    pa, pb = a.get("per_episode"), b.get("per_episode")
    for name, pe in zip(names, (pa, pb)):
        if not pe:
            raise UserError(f"{name} has no per-episode values (a result of dls_quadruped.eval is expected)")
    cmd = "command" if "command" in pa else "command_v_x"
    if pa.get(cmd) != pb.get(cmd):
        raise UserError(f"{names[0]} and {names[1]} are not the same episodes: their per-episode commands differ "
                         "(evaluated with another schedule or code version?)")


def compare(a: dict, b: dict, names: tuple[str, str] = ("A", "B")) -> list[dict]:
    """Paired differences A - B per metric recorded by both, with A's and B's means over the paired episodes."""
    check_paired(a, b, names)
    rows = []
    for key, label in PAIRED_METRICS.items():
        x, y = per_episode_values(a, key), per_episode_values(b, key)
        if x is None or y is None or x.shape != y.shape or x.ndim != 1:
            continue
        d = paired_difference(x, y)
        both = np.isfinite(x) & np.isfinite(y)
        rows.append({"metric": label, "A": float(x[both].mean()) if both.any() else float("nan"),
                     "B": float(y[both].mean()) if both.any() else float("nan"),
                     "A - B": d["mean"], "ci95": d["ci95"], "relative": d["relative"],
                     "relative_ci95": d["relative_ci95"], "episodes": d["episodes"]})
    if not rows:
        raise UserError(f"{names[0]} and {names[1]} share no per-episode metric ({', '.join(PAIRED_METRICS)})")
    return rows


def format_rows(rows: list[dict], names: tuple[str, str]) -> str:
    lines = [f"A = {names[0]}", f"B = {names[1]}",
             f"{'metric':24s} {'A':>9s} {'B':>9s} {'A - B':>9s}  95 % CI (paired, over episodes)   episodes"]
    for r in rows:
        lo, hi = r["ci95"]
        lines.append(f"{r['metric']:24s} {r['A']:9.4f} {r['B']:9.4f} {r['A - B']:+9.4f}  [{lo:+.4f}, {hi:+.4f}]"
                     f"{'':18s}{r['episodes']}")
    return "\n".join(lines)


def _load(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (an evaluation JSON, results/eval/<policy>/<scenario>.json)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise UserError(f"{path}: not JSON ({err})") from None


def main(argv: list[str] | None = None) -> list[dict]:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, help="evaluation JSON of policy A")
    p.add_argument("b", type=Path, help="evaluation JSON of policy B (the reference)")
    p.add_argument("--out", type=Path, default=None, help="also write the differences to this JSON file")
    args = p.parse_args(argv)
    a, b = _load(args.a), _load(args.b)
    names = (f"{args.a} ({a.get('policy', '?')})", f"{args.b} ({b.get('policy', '?')})")
    rows = compare(a, b, names)
    print(f"[compare] {a['scenario']}: {a['episodes']} paired episodes, seed {a['seed']}")
    print(format_rows(rows, names))
    if args.out is not None:
        write_json({"a": str(args.a), "b": str(args.b), "policy_a": a.get("policy"), "policy_b": b.get("policy"),
                    "scenario": a["scenario"], "seed": a["seed"], "episodes": a["episodes"], "rows": rows}, args.out,
                   indent=1)
    return rows


if __name__ == "__main__":
    run_cli(main)
