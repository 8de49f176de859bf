"""Paired comparison of two policies (or closed-loop controllers) evaluated on the same scheduled episodes.

    python -m dls_quadruped.eval --policy new.pt --scenario simple --episodes 256 --out results/eval/new
    python -m dls_quadruped.eval --policy old.pt --scenario simple --episodes 256 --out results/eval/old
    python -m dls_quadruped.eval.compare results/eval/new/simple.json results/eval/old/simple.json [--out d.json]
    python -m dls_quadruped.eval.compare runA/summary.json:rl_warm_start runB/summary.json:rl_baseline

With the same ``--seed`` and ``--episodes`` both evaluations draw every episode's command, pushes and
noise from one schedule (``envs/schedule.py``), so episode e is the same episode for both policies. For
each per-episode metric both results record (survival, mean reward per step, episode length, cost of
transport; on stairs, reached the top and the climbed fraction) this prints the mean over episodes of
(A - B) with its 95 % bootstrap interval over episodes (``eval.metrics.paired_difference``), and A's and
B's own means. An interval that excludes 0 says the
difference is more than the episodes' spread; it says nothing about another seed's training run.

A closed-loop summary (``python -m dls_quadruped.closed_loop``'s ``summary.json``) is named ``FILE:CONTROLLER``
(the controller may be left out when the file holds one): two runs with the same ``--scenario``, ``--seed``,
``--episodes``, ``--seconds`` and command (``--vx``, stairs heights) played the same episodes, so a controller of
one run is paired with a controller of another (e.g. a single and a multi-policy warm start, which need two
runs). Its metrics are the closed loop's per-episode ones (survival, RL reward, initial and rollout costs,
velocity error, cost of transport); an MPC controller's sampler seeds are averaged within each episode and
resampled independently in the interval (``eval.metrics.paired_difference``).

A cell of an experiment script (``experiments/*``: ``OUT/results.json:CELL`` or ``OUT/cells/CELL.json``) is a
closed-loop controller too; its seed is read from ``OUT/config.json``. So a rerun of a table with other policies
(``--variant recipe``) is paired cell by cell with the committed run:

    python -m dls_quadruped.eval.compare NEW/results.json:ws_base_survival OLD/results.json:ws_base_survival
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.metrics import paired_difference
from dls_quadruped.eval.provenance import provenance

PAIRED_METRICS = {"survived": "survival [share]", "reward": "mean reward per step", "length_s": "episode length [s]",
                  "cot": "cost of transport", "reached_top": "stairs: reached the top [share]",
                  "climbed_fraction": "stairs: climbed fraction",
                  "speed_ratio": "speed: achieved / commanded v_x (0 if fell)"}
"""Per-episode values compared between two evaluations, when the scenario records them."""

CLOSED_LOOP_METRICS = {"survived": "survival [share]", "rl_reward": "RL reward per step",
                       "initial_cost": "initial cost",
                       "rollout_cost": "rollout cost, state", "rollout_cost_full": "rollout cost, full J",
                       "vel_error": "velocity error [m/s]", "cost_of_transport": "cost of transport",
                       "reached_top": "stairs: reached the top", "climbed_fraction": "stairs: climbed fraction"}
"""Per-episode values compared between two closed-loop controllers ((S, E) with S sampler seeds, or (1, E))."""

CLOSED_LOOP_SAME = ("scenario", "seed", "episodes", "seconds", "command", "stairs_heights")
"""Closed-loop settings that fix the scheduled episodes: two runs that agree on them played the same episodes."""


def per_episode_values(result: dict, key: str) -> np.ndarray | None:
    """The per-episode values of ``key`` (``"survived"``: 1 - fell) as floats (null -> NaN); None if not recorded."""
    pe = result.get("per_episode") or {}
    if key == "survived":
        return None if "fell" not in pe else 1.0 - np.array(pe["fell"], dtype=float)
    if key == "reached_top":  # stairs: derived from the climbed fraction and the flight's height
        if "climbed_fraction" not in pe or "step_height" not in pe or "steps_per_flight" not in result:
            return None
        from dls_quadruped.eval.stairs import reached_top

        flight = result["steps_per_flight"] * np.array(pe["step_height"], dtype=float)
        return reached_top(np.array(pe["climbed_fraction"], dtype=float), flight).astype(float)
    if key == "speed_ratio":  # speed sweep: tracking and survival in one number
        if "achieved_v_x" not in pe or "command_v_x" not in pe or "fell" not in pe:
            return None
        achieved = np.array([np.nan if v is None else v for v in pe["achieved_v_x"]], dtype=float)
        ratio = achieved / np.array(pe["command_v_x"], dtype=float)
        return np.where(np.array(pe["fell"], dtype=bool), 0.0, ratio)
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


def closed_loop_result(summary: dict, controller: str | None, name: str) -> dict:
    """One controller of a closed-loop summary as a comparable result: its settings, ``per_episode`` values and
    ``kind`` "closed_loop". ``controller`` may be None when the summary holds one controller."""
    controllers = summary.get("controllers") or {}
    if controller is None:
        if len(controllers) != 1:
            raise UserError(f"{name} holds the controllers {', '.join(controllers)}: name one as {name}:CONTROLLER")
        controller = next(iter(controllers))
    if controller not in controllers:
        raise UserError(f"{name} has no controller {controller!r}; it holds {', '.join(controllers) or 'none'}")
    settings = summary.get("settings") or {}
    student = settings.get("student") if controller == "rl_warm_start" else None
    return {"kind": "closed_loop", **settings, "controller": controller,
            "policy": f"{controller}" + (f" ({student})" if student else ""),
            "per_episode": controllers[controller].get("per_episode")}


def cell_result(cell: dict, config: Path) -> dict:
    """One cell of an experiment script as a comparable closed-loop result. Its seed (and, for cells written before
    a cell recorded them, its episode length) come from the run's ``config.json``; without the file the seed is
    None, so it pairs only with another cell that lacks one too."""
    cfg = json.loads(config.read_text()) if config.is_file() else {}
    scenario = cell.get("scenario") or "simple"  # cells written before the field existed ran the simple task
    who = cell.get("student") or cell.get("policy") or ""
    return {"kind": "closed_loop", "scenario": scenario, "seed": cfg.get("seed"), "episodes": cell.get("episodes"),
            "seconds": cell.get("seconds") or cfg.get("seconds"), "command": cell.get("vx"),
            "stairs_heights": cell.get("stairs_heights"), "controller": cell.get("controller"),
            "policy": f"{cell.get('cell')}: {cell.get('controller')} ({who})", "per_episode": cell.get("per_episode")}


def check_paired(a: dict, b: dict, names: tuple[str, str]) -> None:
    """Raise UserError naming the first thing that makes ``a`` and ``b`` not the same episodes."""
    kinds = (a.get("kind", "eval"), b.get("kind", "eval"))
    if kinds[0] != kinds[1]:
        raise UserError(f"{names[0]} is a{' closed-loop' if kinds[0] == 'closed_loop' else 'n eval'} result and "
                         f"{names[1]} a{' closed-loop' if kinds[1] == 'closed_loop' else 'n eval'} one: their episodes "
                         "are not the same (compare two evaluations or two closed-loop controllers)")
    if kinds[0] == "closed_loop":
        for key in CLOSED_LOOP_SAME:
            if a.get(key) != b.get(key):
                raise UserError(f"{names[0]} and {names[1]} are not the same episodes: {key} {a.get(key)!r} vs "
                                 f"{b.get(key)!r} (run both with the same --scenario, --seed, --episodes, --seconds "
                                 "and command)")
        for name, pe in zip(names, (a.get("per_episode"), b.get("per_episode"))):
            if not pe:
                raise UserError(f"{name} has no per-episode values (a summary.json of dls_quadruped.closed_loop is "
                                 "expected)")
        return
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
    closed_loop = a.get("kind") == "closed_loop"
    metrics = CLOSED_LOOP_METRICS if closed_loop else PAIRED_METRICS
    rows = []
    for key, label in metrics.items():
        if closed_loop:
            x, y = (_closed_loop_values(r, key) for r in (a, b))
            if x is None or y is None or x.shape[1] != y.shape[1]:
                continue
        else:
            x, y = per_episode_values(a, key), per_episode_values(b, key)
            if x is None or y is None or x.shape != y.shape or x.ndim != 1:
                continue
        d = paired_difference(x, y)
        xm, ym = (_episode_means(v) for v in (x, y))  # per episode (over sampler seeds), then over the paired ones
        both = np.isfinite(xm) & np.isfinite(ym)
        rows.append({"metric": label, "A": float(xm[both].mean()) if both.any() else float("nan"),
                     "B": float(ym[both].mean()) if both.any() else float("nan"),
                     "A - B": d["mean"], "ci95": d["ci95"], "relative": d["relative"],
                     "relative_ci95": d["relative_ci95"], "episodes": d["episodes"]})
    if not rows:
        raise UserError(f"{names[0]} and {names[1]} share no per-episode metric ({', '.join(metrics)})")
    return rows


def _closed_loop_values(result: dict, key: str) -> np.ndarray | None:
    """(S, E) floats of a closed-loop per-episode metric (null -> NaN), or None if not recorded."""
    v = (result.get("per_episode") or {}).get(key)
    if v is None:
        return None
    return np.array([[np.nan if e is None else e for e in row] for row in (v if v and isinstance(v[0], list) else [v])],
                    dtype=float)


def _episode_means(x: np.ndarray) -> np.ndarray:
    """Per-episode means: (E,) as is, (S, E) averaged over its S seeds ignoring NaN (all-NaN: NaN)."""
    if x.ndim == 1:
        return x
    with np.errstate(all="ignore"):
        n = np.isfinite(x).sum(0)
        return np.where(n > 0, np.nansum(x, 0) / np.maximum(n, 1), np.nan)


def format_rows(rows: list[dict], names: tuple[str, str]) -> str:
    lines = [f"A = {names[0]}", f"B = {names[1]}",
             f"{'metric':24s} {'A':>9s} {'B':>9s} {'A - B':>9s}  95 % CI (paired, over episodes)   episodes"]
    for r in rows:
        lo, hi = r["ci95"]
        lines.append(f"{r['metric']:24s} {r['A']:9.4f} {r['B']:9.4f} {r['A - B']:+9.4f}  [{lo:+.4f}, {hi:+.4f}]"
                     f"{'':18s}{r['episodes']}")
    return "\n".join(lines)


def _load(spec: str) -> dict:
    """An evaluation JSON, or one controller of a closed-loop summary (``FILE:CONTROLLER`` or ``FILE``)."""
    path, controller = Path(spec), None
    if not path.is_file() and ":" in spec:
        head, tail = spec.rsplit(":", 1)
        path, controller = Path(head), tail
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (an evaluation JSON, results/eval/<policy>/<scenario>.json, or "
                                "a closed-loop summary.json[:CONTROLLER])")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise UserError(f"{path}: not JSON ({err})") from None
    if "controllers" in data and "settings" in data:
        return closed_loop_result(data, controller, str(path))
    if "cell" in data and "per_episode" in data:  # OUT/cells/CELL.json
        return cell_result(data, path.parent.parent / "config.json")
    if controller is not None and isinstance(data.get(controller), dict) and "cell" in data[controller]:
        return cell_result(data[controller], path.parent / "config.json")
    if controller is not None:
        raise UserError(f"{path} is not a closed-loop summary (no 'controllers' and 'settings'): ':{controller}' "
                        "names a controller of one; name an evaluation JSON without it")
    return data


def main(argv: list[str] | None = None) -> list[dict]:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", help="evaluation JSON of policy A, or a closed-loop summary.json[:CONTROLLER]")
    p.add_argument("b", help="the reference B, of the same kind as A")
    p.add_argument("--out", type=Path, default=None, help="also write the differences to this JSON file")
    args = p.parse_args(argv)
    a, b = _load(args.a), _load(args.b)
    names = (f"{args.a} ({a.get('policy', '?')})", f"{args.b} ({b.get('policy', '?')})")
    rows = compare(a, b, names)
    print(f"[compare] {a.get('scenario')}: {a.get('episodes')} paired episodes, seed {a.get('seed')}")
    print(format_rows(rows, names))
    if args.out is not None:
        write_json({"a": str(args.a), "b": str(args.b), "policy_a": a.get("policy"), "policy_b": b.get("policy"),
                    "scenario": a.get("scenario"), "seed": a.get("seed"), "episodes": a.get("episodes"), "rows": rows,
                    **provenance()},
                   args.out,
                   indent=1)
    return rows


if __name__ == "__main__":
    run_cli(main)
