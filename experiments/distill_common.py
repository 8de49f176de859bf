"""Shared machinery of the distillation experiments (thesis 7.2: Tables 11-13, Fig. 24-25).

Every experiment is a list of named runs (overrides of ``tasks/agents/distill.yaml``), each trained
with ``seeds`` training seeds (3 at every scale). The seeds of a run train *together*
(``learning.distill_batched``): one collection env of seeds x ``collect.num_envs`` robots, student
k driving its own slice (episode keys k x num_envs + i of one collection schedule, restarted at the
start of every run, so a run does not depend on the runs before it), one stacked MLP and one
optimiser; the runs of one ``Run.group`` (Table 13: the six encodings of one dt and H) join them in
the same env and stack. A run may reuse the datasets of an earlier one (``Run.data_from``: the naive variants of
Table 11 train on the naive run's expert-driven data, so only the schedule differs).

Then every seed and snapshot of every run is evaluated in batched envs on the same scheduled episodes
(:func:`experiments.distill_eval.evaluate`: SP and the test MSE with their intervals).

Scales: ``small`` fits a 2-core machine in minutes (5 epochs x 3000 datapoints: too few for the
students to converge); ``medium`` 10 x 10 000; ``thesis`` uses Table 7 and 7.2.1 sizes (80 000
datapoints per epoch, cap 800 000, 50 000 test datapoints; SP on 512 episodes, not the thesis's
50 000). Outputs under ``--out`` (default ``results/experiments/<name>``): ``runs/<run>/metrics.json``,
``results.json``, ``table.csv``, ``table.md``, the figure, and ``config.json`` (scale, git commit,
expert hash, every run's resolved settings and seconds, the evaluation's seconds). A finished run
(its ``result.pt`` exists) is not trained again.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill import distill_task, load_expert
from dls_quadruped.learning.distill_batched import SeedGroupTrainer, gradient_steps
from dls_quadruped.learning.distill_config import load_distill_config

REPO = Path(__file__).resolve().parents[1]
TASK = "base"
"""Env task of every experiment, trained and evaluated (the expert's; tests swap in a tiny one here and in
``distill_eval``, which imports it)."""
HIDDEN, ACTIVATION = [512, 256, 128], "elu"
SCALES = {
    "small": {"seeds": 3, "train": {"epochs": 5, "datapoints_per_epoch": 3000, "dataset_cap": 800_000},
              "collect": {"num_envs": 64},
              "evaluate": {"test_datapoints": 1000, "test_episodes": 16, "sp_episodes": 16}},
    "medium": {"seeds": 3, "train": {"epochs": 10, "datapoints_per_epoch": 10_000, "dataset_cap": 800_000},
               "collect": {"num_envs": 64},
               "evaluate": {"test_datapoints": 2000, "test_episodes": 32, "sp_episodes": 32}},
    "thesis": {"seeds": 3, "train": {"epochs": 30, "datapoints_per_epoch": 80_000, "dataset_cap": 800_000},
               "collect": {"num_envs": 128},
               "evaluate": {"test_datapoints": 50_000, "test_episodes": 128, "sp_episodes": 512}},
}


@dataclass
class Run:
    """One setting to train with every seed: a name and overrides of the distillation config."""

    name: str
    overrides: dict
    snapshots: bool = False  # keep (and evaluate) every epoch's students
    row: dict = field(default_factory=dict)  # table columns (encoding, batch, ...)
    data_from: str | None = None  # train on this earlier run's datasets instead of collecting
    group: str | None = None  # runs of one group (same schedule, H and dt) collect and train together
    collect: dict | None = None  # task overrides of the collection env (Table 11's narrow collection)


def merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def parse_args(description: str, name: str, extra=None) -> argparse.Namespace:
    """The experiments' shared options; ``extra(parser)`` adds a script's own."""
    p = ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)  # one-line errors
    p.add_argument("--scale", choices=sorted(SCALES), default="small")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / name)
    p.add_argument("--expert", default=str(REPO / "docs" / "policies" / "base_actor.pt"))
    p.add_argument("--keep-datasets", action="store_true", help="keep each run's dataset/ (large at thesis scale)")
    p.add_argument("--only", nargs="*", default=None, help="run only these run names")
    p.add_argument("--train-only", action="store_true",
                   help="train the selected runs and stop (no evaluation or table): split a long script over "
                        "processes with --only, then run it once without either flag")
    if extra is not None:
        extra(p)
    return p.parse_args()


def select(runs: list[Run], only: list[str] | None) -> list[Run]:
    """The runs named in ``only`` (all if None), with the runs whose data they train on, in order."""
    if only is None:
        return list(runs)
    names = set(only) | {r.data_from for r in runs if r.name in only and r.data_from}
    return [r for r in runs if r.name in names]


def scale_config(scale: str) -> dict:
    """The scale's config overrides (without ``seeds``)."""
    return {k: v for k, v in SCALES[scale].items() if k != "seeds"}


def run_config(r: Run, args: argparse.Namespace):
    base = merge(scale_config(args.scale), {"expert": args.expert, "task": str(TASK)})
    return load_distill_config(overrides=merge(base, r.overrides))


def _datasets(run_dir: Path, seeds: list[int]) -> list[DiskDataset] | None:
    paths = [run_dir / f"seed_{s}" / "dataset" for s in seeds]
    return [DiskDataset.open(p) for p in paths] if all(p.is_dir() for p in paths) else None


def _drop_datasets(run_dir: Path) -> None:
    for d in run_dir.glob("seed_*"):
        shutil.rmtree(d)


def train_runs(runs: list[Run], args: argparse.Namespace) -> dict[str, dict]:
    """Train every run with every seed (skipping finished runs); returns {name: result} with
    ``students[k][j]`` the state dict of seed k at snapshot j (j = 0: the last epoch, or every
    epoch 1 .. E with ``snapshots``). With ``args.train_only`` the script stops here (exit 0)."""
    out = _train_runs(runs, args)
    if getattr(args, "train_only", False):
        print(f"[{args.out.name}] --train-only: {len(out)} run(s) trained under {args.out / 'runs'}; run the script "
              "without --train-only / --only for the table", flush=True)
        raise SystemExit(0)
    return out


def _train_runs(runs: list[Run], args: argparse.Namespace) -> dict[str, dict]:
    from dls_quadruped.envs.env import LocomotionEnv

    scale = SCALES[args.scale]
    seeds = list(range(scale["seeds"]))
    expert = load_expert(args.expert)
    out: dict[str, dict] = {}
    done = {r.name for r in runs if (args.out / "runs" / r.name / "result.pt").is_file()}
    todo = [r for r in runs if r.name not in done]
    missing = {r.data_from for r in todo if r.data_from} - {r.name for r in runs}
    if missing:
        raise ValueError(f"runs {sorted(missing)} give data to others but are not in the list (use select())")
    for r in todo:  # a dependant needs its source's datasets: retrain the source if they are gone
        if r.data_from and r.data_from in done and _datasets(args.out / "runs" / r.data_from, seeds) is None:
            done.discard(r.data_from)
    todo = [r for r in runs if r.name not in done]
    for r in runs:
        if r.name in done:
            out[r.name] = torch.load(args.out / "runs" / r.name / "result.pt", weights_only=False)
    if not todo:
        return out
    needed_later = {r.data_from for r in todo if r.data_from}
    batches: list[list[Run]] = []  # runs trained together: a group's runs, or one run
    for r in todo:
        if any(r in b for b in batches):
            continue
        batches.append([x for x in todo if x.group == r.group and not x.data_from] if r.group and not r.data_from
                       else [r])
    for b in batches:
        if len({repr(x.collect) for x in b}) > 1:
            raise ValueError(f"runs {[x.name for x in b]} share a collection env but differ in Run.collect")
    env, env_collect = None, None
    try:
        for k, members in enumerate(batches):
            cfgs = [run_config(r, args) for r in members]
            dirs = [args.out / "runs" / r.name for r in members]
            for d in dirs:
                if d.exists():
                    shutil.rmtree(d)  # an unfinished run starts over (its datasets were for it alone)
                d.mkdir(parents=True)
            robots = len(members) * len(seeds) * scale["collect"]["num_envs"]
            if env is None or env.num_envs != robots or members[0].collect != env_collect:
                if env is not None:
                    env.close()
                env = LocomotionEnv(distill_task(TASK, None, members[0].collect), num_envs=robots, verbose=False)
                env_collect = members[0].collect
            t0 = time.monotonic()
            src = members[0].data_from
            shared = _datasets(args.out / "runs" / src, seeds) if src else None
            print(f"[{args.out.name}] {k + 1}/{len(batches)}: {', '.join(r.name for r in members)}: seeds {seeds} "
                  f"together ({robots} robots)" + (f", on {src}'s data" if shared else ""), flush=True)
            trainer = SeedGroupTrainer(cfgs, seeds, env, expert, dirs, HIDDEN, ACTIVATION, datasets=shared,
                                       printer=lambda *a, **kw: None)
            trainer.start()
            students: list[list[list[dict]]] = [[] for _ in members]  # [member][snapshot][seed]
            while trainer.epoch < trainer.cfg.train.epochs:
                trainer.run_epoch()
                for m, r in enumerate(members):
                    if r.snapshots or trainer.epoch == trainer.cfg.train.epochs:
                        students[m].append(trainer.state_dicts(m))
            seconds = time.monotonic() - t0
            for m, (r, cfg, run_dir) in enumerate(zip(members, cfgs, dirs)):
                result = {"history": trainer.member_history(m), "students": [list(x) for x in zip(*students[m])],
                          "config": cfg.to_dict(), "seeds": seeds, "gradient_steps": gradient_steps(cfg),
                          "snapshot_epochs": (list(range(1, cfg.train.epochs + 1)) if r.snapshots
                                              else [cfg.train.epochs]),
                          "seconds": seconds / len(members), "trained_with": [x.name for x in members],
                          "group_seconds": seconds}
                tmp = run_dir / "result.pt.tmp"  # result.pt marks the run finished: never a partial one
                torch.save(result, tmp)
                os.replace(tmp, run_dir / "result.pt")
                write_json({k: v for k, v in result.items() if k != "students"}, run_dir / "metrics.json")
                if not args.keep_datasets and r.name not in needed_later:
                    _drop_datasets(run_dir)
                out[r.name] = result
            h = trainer.history[-1]
            print(f"[{args.out.name}]   train loss {np.mean(h['train_loss']):.4f} (mean of {len(h['train_loss'])} "
                  f"students), dataset {h['dataset_size']} each, {seconds:.0f} s", flush=True)
    finally:
        if env is not None:
            env.close()
        if not args.keep_datasets:
            for name in needed_later:
                _drop_datasets(args.out / "runs" / name)
    return out


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def sp_cell(sp: dict) -> str:
    return f"{100 * sp['sp']:.1f} % [{100 * sp['ci95'][0]:.1f}, {100 * sp['ci95'][1]:.1f}]"


def seeds_cell(values: list[float], percent: bool = True) -> str:
    return " / ".join(f"{100 * v:.1f}" if percent else f"{v:.3f}" for v in values)


def mse_cell(m: dict) -> str:
    return f"{m['mse']:.3f} [{m['ci95'][0]:.3f}, {m['ci95'][1]:.3f}]"


def summary_row(trained: dict, ev: dict, name: str) -> dict:
    """The columns every table shares, for the last snapshot of ``name``."""
    h = trained[name]["history"][-1]
    sp, mse = ev["sp"][name][-1], ev["mse"][name][-1]
    return {"MSE [95 % CI]": mse_cell(mse), "MSE per seed": seeds_cell(mse["per_seed"], percent=False),
            "SP [95 % CI]": sp_cell(sp), "SP per seed [%]": seeds_cell([p["sp"] for p in sp["per_seed"]]),
            "survival": pct(sp["survival"]["rate"]), "seeds": sp["seeds"], "SP episodes": sp["episodes"],
            "test windows": mse["windows"], "train datapoints": h["dataset_size"], "epochs": h["epoch"],
            "gradient steps": trained[name]["gradient_steps"]}


def write_config(args: argparse.Namespace, runs: list[Run], trained: dict, extra: dict | None = None) -> None:
    write_json({"scale": args.scale, "scale_settings": SCALES[args.scale], **provenance(),
                "expert": args.expert, "expert_sha256": hashlib.sha256(Path(args.expert).read_bytes()).hexdigest(),
                "runs": {r.name: {"overrides": r.overrides, "data_from": r.data_from,
                                  "resolved": trained[r.name]["config"], "seeds": trained[r.name]["seeds"],
                                  "train_seconds": trained[r.name]["seconds"]} for r in runs if r.name in trained},
                **(extra or {})}, args.out / "config.json")
