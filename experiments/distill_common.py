"""Shared machinery of the distillation experiments (thesis 7.2: Tables 11-13, Fig. 24-25).

Every experiment is a list of named runs (overrides of ``tasks/agents/distill.yaml``). Runs are
trained one after the other in one collection env, without SP; then SP is measured for every
student (and every per-epoch snapshot a figure needs) *at once*: one big env holds
``sp_episodes`` robots per policy, so the 750 steps of a 15 s episode are paid three times in all
(expert, untrained students, trained students) instead of three times per run. Policy p drives
robots [p E, (p+1) E); expert and untrained student are run on the same robots and seeds, so SP
(eq. 7.2.2) compares the same episodes.

Scales: ``small`` fits a 2-core machine in minutes (5 epochs x 3000 datapoints: too few for the
students to converge, it checks the pipeline); ``medium`` (10 x 10 000) in about three minutes
per run; ``thesis`` uses Table 7 and 7.2.1 sizes
(80 000 datapoints per epoch, cap 800 000, 50 000 test datapoints, 50 000 SP episodes).
Outputs under ``--out`` (default ``results/experiments/<name>``): ``runs/<run>/metrics.json``,
``results.json``, ``table.csv``, ``table.md``, the figure, and ``config.json`` (scale, git commit,
expert hash, every run's resolved settings). A finished run (its ``metrics.json`` exists) is not
trained again.
"""

from __future__ import annotations

import argparse
import copy
import csv
import hashlib
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from dls_quadruped.core.json_io import write_json
from dls_quadruped.learning.distill import distill_task, load_expert
from dls_quadruped.learning.distill_config import load_distill_config
from dls_quadruped.learning.distill_metrics import (
    episode_returns,
    simulation_performance,
    survival,
)
from dls_quadruped.learning.distill_trainer import DistillTrainer
from dls_quadruped.learning.student import Student

REPO = Path(__file__).resolve().parents[1]
TASK = "base"
"""Env task of every experiment (the expert's; tests swap in a tiny one)."""
SCALES = {
    "small": {"train": {"epochs": 5, "datapoints_per_epoch": 3000, "dataset_cap": 800_000},
              "collect": {"num_envs": 64}, "evaluate": {"test_datapoints": 1000, "sp_episodes": 16}},
    "medium": {"train": {"epochs": 10, "datapoints_per_epoch": 10_000, "dataset_cap": 800_000},
               "collect": {"num_envs": 64}, "evaluate": {"test_datapoints": 2000, "sp_episodes": 32}},
    "thesis": {"train": {"epochs": 30, "datapoints_per_epoch": 80_000, "dataset_cap": 800_000},
               "collect": {"num_envs": 128}, "evaluate": {"test_datapoints": 50_000, "sp_episodes": 50_000}},
}


@dataclass
class Run:
    """One student to train: a name and overrides of the distillation config (merged on the scale's)."""

    name: str
    overrides: dict
    snapshots: bool = False  # keep every epoch's student for SP over training
    row: dict = field(default_factory=dict)  # table columns (encoding, batch, ...)


def merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def parse_args(description: str, name: str) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scale", choices=sorted(SCALES), default="small")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / name)
    p.add_argument("--expert", default=str(REPO / "docs" / "policies" / "base_actor.pt"))
    p.add_argument("--keep-datasets", action="store_true", help="keep each run's dataset/ (large at thesis scale)")
    p.add_argument("--only", nargs="*", default=None, help="run only these run names")
    return p.parse_args()


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _uncommitted() -> list[str]:
    """Files of the working tree that differ from the commit (another developer's edits in progress
    change what the env runs, so they are recorded with the results)."""
    try:
        out = subprocess.run(["git", "status", "--short", "--untracked-files=no"], cwd=REPO, capture_output=True,
                             text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return ["unknown"]
    return [line.strip() for line in out.splitlines() if line.strip()]


def train_runs(runs: list[Run], args: argparse.Namespace) -> dict[str, dict]:
    """Train every run (skipping finished ones); returns {name: {"history", "students": [state dicts]}}."""
    from dls_quadruped.envs.env import LocomotionEnv

    scale = SCALES[args.scale]
    expert = load_expert(args.expert)
    sha = hashlib.sha256(Path(args.expert).read_bytes()).hexdigest()
    out: dict[str, dict] = {}
    todo = [r for r in runs if not (args.out / "runs" / r.name / "result.pt").is_file()]
    for r in runs:
        if r not in todo:
            out[r.name] = torch.load(args.out / "runs" / r.name / "result.pt", weights_only=False)
    if not todo:
        return out
    num_envs = scale["collect"]["num_envs"]
    env = LocomotionEnv(distill_task(TASK, None), num_envs=num_envs, verbose=False)
    try:
        for k, r in enumerate(todo):
            cfg = load_distill_config(overrides=merge(merge(scale, {"expert": args.expert, "task": str(TASK)}), r.overrides))
            run_dir = args.out / "runs" / r.name
            if run_dir.exists():
                shutil.rmtree(run_dir)  # an unfinished run starts over (its datasets were for it alone)
            run_dir.mkdir(parents=True)
            t0 = time.monotonic()
            print(f"[{args.out.name}] run {k + 1}/{len(todo)} {r.name}", flush=True)
            trainer = DistillTrainer(cfg, env, expert, run_dir, [512, 256, 128], "elu",
                                     expert_info={"path": args.expert, "sha256": sha}, sp=False,
                                     printer=lambda *a, **kw: None)
            trainer.open_datasets(resume=False)
            trainer.collect_test_set()
            students = [copy.deepcopy(trainer.untrained.state_dict())]
            while trainer.epoch < cfg.train.epochs:
                trainer.run_epoch()
                if r.snapshots or trainer.epoch == cfg.train.epochs:
                    students.append(copy.deepcopy(trainer.student.state_dict()))
            result = {"history": trainer.history, "students": students, "config": cfg.to_dict(),
                      "snapshot_epochs": list(range(cfg.train.epochs + 1)) if r.snapshots else [0, cfg.train.epochs],
                      "seconds": time.monotonic() - t0}
            torch.save(result, run_dir / "result.pt")
            write_json({k: v for k, v in result.items() if k != "students"}, run_dir / "metrics.json")
            if not args.keep_datasets:
                shutil.rmtree(run_dir / "dataset")
            h = trainer.history[-1]
            print(f"[{args.out.name}]   test MSE {h['test_mse']:.4f}, dataset {h['dataset_size']}, "
                  f"{result['seconds']:.0f} s", flush=True)
            out[r.name] = result
    finally:
        env.close()
    return out


def _student(state: dict, cfg: dict) -> Student:
    from dls_quadruped.mpc.config import EncodingConfig

    e = cfg["encoding"]
    s = Student(259, EncodingConfig(e["p"], e["F"], e["horizon"], e["constrained_fit"]), [512, 256, 128], "elu")
    s.load_state_dict(state)
    return s.eval()


def batched_sp(trained: dict[str, dict], args: argparse.Namespace, seed: int = 2000) -> dict[str, list[dict]]:
    """SP of every trained snapshot of every run, all policies in one env; {run: [SP per snapshot]}.

    Three passes over the same robots and seed (eq. 7.2.2's "same conditions"): the expert on every
    robot, each slot's *untrained* student (snapshot 0 of its run, r_0), then each slot's snapshot.
    """
    from dls_quadruped.envs.env import LocomotionEnv

    per = SCALES[args.scale]["evaluate"]["sp_episodes"]
    slots = [(name, i) for name, res in trained.items() for i in range(1, len(res["students"]))]
    max_envs = 1024  # robots per batch of episodes; more policies than fit go in several batches
    per_batch = max(1, max_envs // per)
    results: dict[str, list[dict]] = {name: [] for name in trained}
    expert = load_expert(args.expert)
    for b in range(0, len(slots), per_batch):
        group = slots[b:b + per_batch]
        n = len(group) * per
        env = LocomotionEnv(distill_task(TASK, None), num_envs=n, verbose=False)
        try:
            nets = [_student(trained[name]["students"][i], trained[name]["config"]) for name, i in group]
            untrained = [_student(trained[name]["students"][0], trained[name]["config"]) for name, _ in group]

            def mixed(policies):
                def act(obs: torch.Tensor) -> torch.Tensor:
                    return torch.cat([net.first_action(obs[j * per:(j + 1) * per]) for j, net in enumerate(policies)])
                return act

            t0 = time.monotonic()
            print(f"[{args.out.name}] SP: {len(group)} policies x {per} episodes of "
                  f"{env.max_episode_length_s:g} s ({n} robots): expert, untrained, trained", flush=True)
            r_exp = episode_returns(env, expert, [seed])
            r_0 = episode_returns(env, mixed(untrained), [seed])
            r_pol = episode_returns(env, mixed(nets), [seed])
            print(f"[{args.out.name}] SP batch done in {time.monotonic() - t0:.0f} s", flush=True)
        finally:
            env.close()
        for j, (name, i) in enumerate(group):
            sl = slice(j * per, (j + 1) * per)
            sp = simulation_performance(r_pol["return"][sl], r_exp["return"][sl], r_0["return"][sl], seed=j)
            sp["survival"] = survival(r_pol["survived"][sl])
            sp["survival_expert"] = survival(r_exp["survived"][sl])
            sp["survival_untrained"] = survival(r_0["survived"][sl])
            sp["epoch"] = trained[name]["snapshot_epochs"][i]
            results[name].append(sp)
    for rows in results.values():
        rows.sort(key=lambda r: r["epoch"])
    return results


def write_table(rows: list[dict], columns: list[str], path_base: Path, title: str) -> None:
    """``<base>.csv`` and ``<base>.md`` with the given columns."""
    path_base.parent.mkdir(parents=True, exist_ok=True)
    with open(path_base.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in columns})
    lines = [f"**{title}**", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in columns) + " |" for r in rows]
    path_base.with_suffix(".md").write_text("\n".join(lines) + "\n")


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def sp_cell(sp: dict) -> str:
    return f"{100 * sp['sp']:.1f} % [{100 * sp['ci95'][0]:.1f}, {100 * sp['ci95'][1]:.1f}]"


def summary_row(trained: dict, sp: dict, name: str) -> dict:
    h = trained[name]["history"][-1]
    final = sp[name][-1]
    return {"MSE": f"{h['test_mse']:.4f}", "SP [95 % CI]": sp_cell(final), "survival": pct(final["survival"]["rate"]),
            "SP episodes": final["episodes"], "test datapoints": trained[name]["config"]["evaluate"]["test_datapoints"],
            "train datapoints": h["dataset_size"], "epochs": h["epoch"]}


def write_config(args: argparse.Namespace, runs: list[Run], trained: dict, extra: dict | None = None) -> None:
    write_json({"scale": args.scale, "scale_settings": SCALES[args.scale], "git_commit": _git_commit(),
                "uncommitted_at_end": _uncommitted(),
                "expert": args.expert, "expert_sha256": hashlib.sha256(Path(args.expert).read_bytes()).hexdigest(),
                "runs": {r.name: {"overrides": r.overrides, "resolved": trained[r.name]["config"],
                                  "train_seconds": trained[r.name]["seconds"]} for r in runs if r.name in trained},
                **(extra or {})}, args.out / "config.json")
