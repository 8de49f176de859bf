"""Choose a thesis-5.3 run's policy on validation episodes ([mpc_cost_plan.md](docs/experiments/mpc_cost_plan.md)).

Every candidate -- the DAgger student the runs start from (not for a run from scratch: ``--no-student``), the
run's checkpoints at multiples of ``--every`` iterations and its newest, and any ``--extra`` checkpoint -- drives
``base_mpc_cost`` alone (deterministic: the actor's mean) on the simple task's **validation** episodes
(``--episodes``, 15 s, the eval's validation seed: disjoint from the test episodes every closed-loop cell plays),
the env as the evaluation builds it (flat, no noise or perturbation, one fixed command per episode) with the run's
own training objective as its reward: the Table-4 reward plus ``W`` times the trajectory cost c
(``mpc_trajectory_cost``, the task's parameters; no term when ``W = 0``). The candidate with the highest mean over
episodes of the per-episode reward per step is the run's policy; a tie goes to the later one. Also recorded per
candidate: survival and the mean c per episode (the term's value whatever ``W``).

    python -m experiments.mpc_cost_select --weight -0.1 --run runs/base_mpc_cost/w0.1_s1 \\
        --out docs/experiments/mpc_cost/selection/w0.1_s1 --export runs/mpc_cost/w0.1_s1.pt2

Writes ``<out>/selection.json`` (every candidate's scores, the choice, provenance); each candidate's evaluation is
cached as ``<out>/<candidate's file stem>.json``, so an interrupted selection continues (and a selection run while the
training still runs evaluates only the new checkpoints the next time). ``--export`` writes the chosen
policy as a student program (``experiments/mpc_cost_export.py``) for the closed loop's ``--student``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, UserError, positive_int, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.managers.action import resolve_horizon_config
from dls_quadruped.envs.mdp import rewards
from dls_quadruped.envs.recorder import record
from dls_quadruped.envs.sections import replace_sections
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import EvalOptions, split_seed
from dls_quadruped.eval.select import candidates, run_checkpoints
from dls_quadruped.eval.velocity_tracking import flat_task, simple_commands
from dls_quadruped.learning.policy_file import load_module
from dls_quadruped.learning.runner import read_checkpoint
from dls_quadruped.learning.student import export_student, metadata
from experiments.mpc_cost_export import student_from_actor

REPO = Path(__file__).resolve().parents[1]
TASK = "base_mpc_cost"
STUDENT = Path("docs/policies/base_recipe_student_first_spline_h10.pt2")
"""The DAgger student every run starts from (relative to the repository root, where the scripts run)."""
TERM = "mpc_trajectory_cost"


def objective_task(commands: np.ndarray, opts: EvalOptions, weight: float):
    """``base_mpc_cost`` as the evaluation builds it (``flat_task``), its reward the Table-4 reward plus ``weight``
    times the trajectory cost with the task's own parameters (none when ``weight`` is 0)."""
    task = flat_task(commands, opts, task=TASK)
    term = load_task(TASK).data["rewards"][TERM]
    reward = dict(task.data["rewards"])
    if weight != 0.0:
        reward[TERM] = {**term, "weight": float(weight)}
    return replace_sections(task, {"rewards": reward}, source=f"<mpc_cost_select: Table-4 reward + {weight:g} c>")


def candidate_policy(path: Path):
    """(obs (B, 259) -> encoded horizon (B, 64), description) of a student program or a ``base_mpc_cost``
    checkpoint (its actor's mean)."""
    if path.suffix == ".pt2":
        program = load_module(path)
        return lambda obs: _first(program(obs)), "student program"
    ckpt = read_checkpoint(path)
    enc, _ = resolve_horizon_config(load_task(TASK))
    student = student_from_actor(ckpt["actor_state_dict"], enc, int(ckpt["obs_dims"]["policy"]))
    return student, f"checkpoint, iteration {int(ckpt['iter'])}"


def _first(out):
    """A program's output: the horizon, or a tuple whose first entry is the horizon."""
    return out[0] if isinstance(out, tuple) else out


def evaluate(path: Path, weight: float, opts: EvalOptions, params: dict, num_steps: int | None = None) -> dict:
    """One candidate alone on ``opts``' episodes for ``num_steps`` steps (None: one episode): per-episode reward per
    step, mean c (the steps whose state after the step still belongs to the episode), survival."""
    from dls_quadruped.envs.env import LocomotionEnv

    policy, kind = candidate_policy(path)
    cmds = simple_commands(opts.episodes, opts.seed)
    env = LocomotionEnv(objective_task(cmds, opts, weight), num_envs=opts.episodes, seed=opts.seed, verbose=False)
    cost = {"c": lambda e: rewards.mpc_trajectory_cost(e, params["reference_cost"], params["com_height"],
                                                       params["clip"], split_every=10**9)}
    try:
        torch.manual_seed(opts.seed)
        rec = record(env, policy=policy, obs_group="policy", after=cost, num_steps=num_steps, desc=path.name)
    finally:
        env.close()
    reward = np.nanmean(rec.masked(rec.reward, rec.active), axis=0)          # (E,) reward per step
    c = np.nanmean(rec.masked(rec.after["c"].astype(np.float64), rec.valid), axis=0)  # (E,) mean c
    return {"candidate": str(path), "kind": kind, "weight": weight, "seed": opts.seed, "episodes": opts.episodes,
            "objective_per_step": float(reward.mean()), "survival": float(1.0 - rec.fell.mean()),
            "c_mean": float(np.nanmean(c)),
            "per_episode": {"objective_per_step": reward.tolist(), "c_mean": c.tolist(), "fell": rec.fell.tolist()}}


def choose_latest(scores: list[tuple[str, float]]) -> int:
    """Index of the highest score; a tie goes to the later candidate (the list is in training order)."""
    finite = [(i, v) for i, (_, v) in enumerate(scores) if np.isfinite(v)]
    if not finite:
        raise UserError("no candidate has a finite validation score")
    best = max(v for _, v in finite)
    return max(i for i, v in finite if v == best)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--weight", type=float, required=True, help="the run's trajectory-cost weight W (<= 0)")
    p.add_argument("--run", type=Path, default=None, help="run directory with model_<it>.pt checkpoints")
    p.add_argument("--extra", type=Path, nargs="*", default=[],
                   help="more checkpoints (e.g. a committed resume copy), after the run's, in training order")
    p.add_argument("--student", type=Path, default=STUDENT, help="the DAgger student the runs started from")
    p.add_argument("--no-student", action="store_true",
                   help="a run trained from scratch: the student it did not start from is not a candidate")
    p.add_argument("--every", type=positive_int, default=50)
    p.add_argument("--episodes", type=positive_int, default=64, help="validation episodes (even)")
    p.add_argument("--seed", type=int, default=0, help="the evaluation seed whose validation split is played")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--export", type=Path, default=None, help="write the chosen policy here as a student program")
    p.add_argument("--networks", type=Path, default=None,
                   help="write the chosen checkpoint's actor and critic here (train --init-from; not for the student)")
    args = p.parse_args(argv)
    if args.weight > 0:
        p.error(f"--weight is a cost weight, <= 0; got {args.weight:g}")
    if args.episodes % 2:
        p.error(f"--episodes must be even (mirrored command pairs), got {args.episodes}")
    if args.run is None and not args.extra:
        p.error("give --run or --extra: at least one trained candidate")
    return args


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    torch.set_num_threads(1)
    todo = [] if args.no_student else [args.student]
    if args.run is not None:
        if not args.run.is_dir():
            raise UserError(f"--run {args.run}: not a directory")
        todo += list(candidates(run_checkpoints(args.run), args.every).values())
    todo += list(args.extra)
    for path in todo:
        if not path.is_file():
            raise UserError(f"candidate {path} not found")
    opts = EvalOptions(episodes=args.episodes, seed=split_seed(args.seed, "validation"), num_workers=0)
    params = load_task(TASK).data["rewards"][TERM]["params"]
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for path in todo:
        cached = args.out / f"{path.stem}.json"  # a stem met twice (another run's file) fails the check below
        res = json.loads(cached.read_text()) if cached.is_file() else None
        if res is None or res["candidate"] != str(path) or res["seed"] != opts.seed or res["weight"] != args.weight \
                or res["episodes"] != opts.episodes:
            res = evaluate(path, args.weight, opts, params)
            write_json({**res, **provenance()}, cached, indent=1)
        results.append(res)
        print(f"[select] {path}: objective {res['objective_per_step']:.4f} per step, c {res['c_mean']:.2f}, "
              f"survival {res['survival']:.3f}", flush=True)
    chosen = choose_latest([(r["candidate"], r["objective_per_step"]) for r in results])
    summary = {"weight": args.weight, "split": "validation", "seed": args.seed, "validation_seed": opts.seed,
               "episodes": opts.episodes, "every": args.every,
               "candidates": [{k: r[k] for k in ("candidate", "kind", "objective_per_step", "c_mean", "survival")}
                              for r in results],
               "chosen": results[chosen]["candidate"], **provenance()}
    write_json(summary, args.out / "selection.json", indent=1)
    print(f"[select] chosen {summary['chosen']}")
    if args.export is not None:
        export(Path(summary["chosen"]), args.export)
    if args.networks is not None:
        networks(Path(summary["chosen"]), args.networks)
    return summary


def networks(path: Path, out: Path) -> None:
    """The actor and critic of a chosen checkpoint (no optimiser, RNG or episodes: ~1/3 of a resume copy), written
    atomically; a student program has no critic, so nothing is written for it."""
    if path.suffix == ".pt2":
        print(f"[select] {path} is the student: no networks to write")
        return
    ckpt = read_checkpoint(path)
    keep = {k: ckpt[k] for k in ("actor_state_dict", "critic_state_dict", "iter", "obs_dims", "num_actions")}
    keep["infos"] = {"source": str(path), "selected_on": "validation episodes (experiments/mpc_cost_select.py)"}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    torch.save(keep, tmp)
    os.replace(tmp, out)
    print(f"[select] wrote {out}")


def export(path: Path, out: Path) -> None:
    """The chosen candidate as a student program at ``out`` (a student program is copied as it is)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".pt2":
        out.write_bytes(path.read_bytes())
        src = path.with_suffix(".json")
        if src.is_file():
            out.with_suffix(".json").write_text(src.read_text())
        return
    enc, dt = resolve_horizon_config(load_task(TASK))
    ckpt = read_checkpoint(path)
    obs_dim = int(ckpt["obs_dims"]["policy"])
    student = student_from_actor(ckpt["actor_state_dict"], enc, obs_dim)
    extra = {"source": str(path), "iteration": int(ckpt["iter"]), "algorithm": "ppo_mpc_cost"}
    export_student(student, metadata(enc, dt, obs_dim, extra), out)
    print(f"[select] wrote {out}")


if __name__ == "__main__":
    run_cli(main)
