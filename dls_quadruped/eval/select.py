"""Choose a run's checkpoint on validation episodes, so that the test episodes stay unseen.

    python -m dls_quadruped.eval.select runs/base/<run> [--scenario simple] [--every 50] [--episodes 256]
    make select RUN=runs/base/<run> SCENARIO=simple

Every ``model_<it>.pt`` of the run whose iteration is a multiple of ``--every`` (and the newest) is
evaluated on the scenario's **validation** episodes (``eval --split validation``: the same scenario,
disjoint episodes) and the one with the highest mean per-episode ``--metric`` is chosen. Report the
chosen checkpoint with ``python -m dls_quadruped.eval --split test`` (the default) and nothing that chose
it has seen those episodes. Writes ``<out>/selection.json`` (default ``<run>/selection/<scenario>``) and
keeps every evaluation beside it, so an interrupted selection continues where it stopped and a later one
with more checkpoints evaluates only the new ones.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    positive_int,
    run_cli,
    torch_device,
)
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.compare import PAIRED_METRICS, per_episode_values
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import EvalOptions, split_seed
from dls_quadruped.eval.scenarios import SCENARIOS

DEFAULT_METRIC = {"survival": "survived", "survival_sweep": "survived", "stairs": "climbed_fraction",
                  "speed": "speed_ratio"}
"""The per-episode metric a scenario is selected on when ``--metric`` is not given (else ``reward``)."""

_CHECKPOINT = re.compile(r"model_(\d+)\.pt")


def run_checkpoints(run: Path) -> dict[int, Path]:
    """{iteration: path} of the run's ``model_<it>.pt``, in iteration order."""
    found = {int(m.group(1)): p for p in run.glob("model_*.pt") if (m := _CHECKPOINT.fullmatch(p.name))}
    return dict(sorted(found.items()))


def candidates(checkpoints: dict[int, Path], every: int | None) -> dict[int, Path]:
    """The checkpoints to evaluate: iterations that are positive multiples of ``every`` (train saves
    ``model_<k * save_interval>.pt``; all when None), and the newest."""
    if not checkpoints:
        return {}
    newest = max(checkpoints)
    return {it: p for it, p in checkpoints.items()
            if every is None or (it > 0 and it % every == 0) or it == newest}


def metric_value(result: dict, metric: str) -> float:
    """Mean over episodes of the per-episode ``metric`` (NaN episodes left out)."""
    values = per_episode_values(result, metric)
    if values is None:
        raise UserError(f"scenario {result.get('scenario')!r} records no per-episode {metric!r}; "
                        f"choose --metric from those it records: "
                        f"{[k for k in PAIRED_METRICS if per_episode_values(result, k) is not None]}")
    return float(np.nanmean(values))


def choose(values: dict[int, float]) -> int:
    """The iteration with the highest value; a tie goes to the earliest (fewer samples, same score)."""
    finite = {it: v for it, v in values.items() if np.isfinite(v)}
    if not finite:
        raise UserError("no checkpoint has a finite validation score")
    best = max(finite.values())
    return min(it for it, v in finite.items() if v == best)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", type=Path, help="run directory with model_<it>.pt checkpoints")
    p.add_argument("--scenario", default="simple", choices=sorted(SCENARIOS))
    p.add_argument("--metric", default=None, choices=sorted(PAIRED_METRICS),
                   help="per-episode metric to maximise (default: survived for survival scenarios, "
                        "climbed_fraction for stairs, else reward)")
    p.add_argument("--every", type=positive_int, default=None,
                   help="only checkpoints whose iteration is a positive multiple of this, and the newest "
                        "(default: all)")
    p.add_argument("--episodes", type=positive_int, default=None, help="validation episodes (default: the scenario's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-workers", type=int, default=-1)
    p.add_argument("--device", type=torch_device, default="cpu")
    p.add_argument("--out", type=Path, default=None, help="default <run>/selection/<scenario>")
    args = p.parse_args(argv)
    args.metric = args.metric or DEFAULT_METRIC.get(args.scenario, "reward")
    try:
        args.validation_seed = split_seed(args.seed, "validation")
    except ValueError as err:
        p.error(f"argument --seed: {err}")
    return args


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    if not args.run.is_dir():
        raise UserError(f"run directory {args.run} not found")
    todo = candidates(run_checkpoints(args.run), args.every)
    if not todo:
        raise UserError(f"{args.run} holds no model_<it>.pt checkpoint")
    scenario = SCENARIOS[args.scenario]
    opts = EvalOptions(episodes=args.episodes or scenario.default_episodes, seed=args.validation_seed,
                       num_workers=args.num_workers, device=args.device)
    out = args.out or args.run / "selection" / args.scenario
    out.mkdir(parents=True, exist_ok=True)
    values: dict[int, float] = {}
    for it, ckpt in todo.items():
        cached = out / f"model_{it}.json"
        res = json.loads(cached.read_text()) if cached.is_file() else None
        if res is None or res.get("seed") != opts.seed or \
                res.get("episodes_per_condition", res.get("episodes")) != opts.episodes:
            res = scenario.evaluate(ckpt, opts)
            res["split"] = "validation"
            res.update(provenance())
            write_json(res, cached, indent=1)
        values[it] = metric_value(res, args.metric)
        print(f"[select] {ckpt.name}: validation {args.metric} {values[it]:.4f}", flush=True)
    chosen = choose(values)
    summary = {"run": str(args.run), "scenario": args.scenario, "metric": args.metric, "split": "validation",
               "seed": args.seed, "validation_seed": opts.seed, "episodes": opts.episodes,
               "candidates": [{"iteration": it, "checkpoint": str(todo[it]), "value": v} for it, v in values.items()],
               "chosen": {"iteration": chosen, "checkpoint": str(todo[chosen]), "value": values[chosen]},
               **provenance()}
    write_json(summary, out / "selection.json", indent=1)
    print(f"[select] chosen {todo[chosen]} ({args.metric} {values[chosen]:.4f} on {opts.episodes} validation "
          f"episodes); report it with: python -m dls_quadruped.eval --policy {todo[chosen]} --scenario {args.scenario}")
    return summary


if __name__ == "__main__":
    run_cli(main)
