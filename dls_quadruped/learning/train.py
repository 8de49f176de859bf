"""Train a PPO policy on a task with rsl-rl-lib.

    python -m dls_quadruped.learning.train --task rough --num-envs 64 --iterations 100 --device cpu --seed 0
    python -m dls_quadruped.learning.train --task rough --resume          # continue the latest run
    python -m dls_quadruped.learning.train --task base --set agent.algorithm.entropy_coef=0.005 \\
        --set env.episode_length_s=10
    python -m dls_quadruped.learning.train --task speed --init-from docs/policies/base_networks.pt
    python -m dls_quadruped.learning.train --task base --checkpoint-copy docs/policies/base_resume.pt
    python -m dls_quadruped.learning.train --task base --resume-from docs/policies/base_resume.pt  # another machine
    python -m dls_quadruped.learning.train --task base --device cuda --backend cuda --num-envs 4096 --time-limit 540

Checkpoints (written atomically, with the env's curricula, terrain levels, command ranges, reward
weights and RNG state) every ``--save-interval`` iterations (default: a tenth of the run, at most
``agent.save_interval``), whenever ``--save-every-min`` minutes passed since the last one, at the
end, and on SIGINT/SIGTERM (at the end of the current iteration; a second signal stops at once).
``--resume`` reloads the newest readable checkpoint of the newest run (or of ``--run-dir``),
restores the env state and continues for ``--iterations`` more; a checkpoint that does not fit
the task is refused before anything in the run directory is written. ``--resume-from CKPT``
continues from a checkpoint file anywhere (e.g. one committed beside the policies, written there by
``--checkpoint-copy``) in a new run directory: networks, optimiser, learning rate, iteration,
curricula, terrain levels, command ranges, the episodes in progress (simulator state included) and
every RNG, so its first iteration is the one the uninterrupted run would have taken (tested).
``--time-limit SECONDS`` (counted from the start of the process, so the env's build and compiles are in it)
ends the run at the end of the last iteration that leaves time for one more and for the closing save and
export, with its checkpoint, curve rows and exported policy written, and exit status 0; ``--resume`` then
continues it (a job that fits a short GPU lease). ``--init-from`` starts a new
run from another run's actor and critic (a checkpoint file or a run directory's newest one; fresh
optimiser, iteration 0, the task's own curricula; see ``AtomicOnPolicyRunner.init_networks``); it is
recorded in the run directory's ``init_from.yaml``. At the end the actor is exported as a
``torch.export`` program (``exported/policy.pt2``) and as ONNX (``exported/policy.onnx``).
Distributed: ``torchrun --standalone --nproc_per_node=N -m dls_quadruped.learning.train ...`` runs N
processes, each with its own ``--num-envs`` robots and seed ``--seed + rank``, all-reducing the
gradients (gloo with ``--device cpu``; NCCL with ``--device cuda``, which becomes ``cuda:$LOCAL_RANK``).
Rank 0 chooses (or checks) the run directory and tells the others; only rank 0 writes to it.
See docs/train.md.
"""

from __future__ import annotations

import argparse
import os
import signal
from pathlib import Path

import torch

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    add_set_argument,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
    set_overrides,
    torch_device,
)
from dls_quadruped.envs.config import load_task, merge_overrides, save_resolved
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import resume_state
from dls_quadruped.learning.distributed import (
    Ranks,
    broadcast_from_main,
    close_distributed,
    init_distributed,
)
from dls_quadruped.learning.policy_export import export_policy
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    CheckpointMismatch,
    TrainingInterrupted,
    latest_run,
    new_run_dir,
    newest_readable_checkpoint,
    read_checkpoint,
    remove_stale_tmp,
    runner_config,
    sha256_file,
    write_yaml,
)
from dls_quadruped.learning.time_limit import Deadline, TimeLimitReached

DEFAULT_SAVE_EVERY_MIN = 5.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="base", help="task name in tasks/ or a YAML path")
    p.add_argument("--num-envs", type=positive_int, default=None,
                   help="robots (default: the task's env.num_envs; with --resume / --resume-from, the checkpoint's)")
    p.add_argument("--iterations", type=positive_int, default=None,
                   help="PPO iterations (default: agent.max_iterations)")
    p.add_argument("--device", type=torch_device, default="cpu", help="cpu, cuda or cuda:<index>")
    p.add_argument("--seed", type=int, default=None,
                   help="seed (default: 0, or the checkpoint's with --resume/--resume-from, which must match)")
    p.add_argument("--resume", action="store_true", help="continue from the newest readable checkpoint")
    p.add_argument("--resume-from", type=Path, default=None, metavar="CKPT",
                   help="continue from this checkpoint file (e.g. copied from another machine) in a new run "
                        "directory, with its optimiser, env state and RNG; not with --resume or --init-from")
    p.add_argument("--checkpoint-copy", type=Path, default=None, metavar="PATH",
                   help="also write every checkpoint (atomically) to PATH, e.g. docs/policies/base_resume.pt, "
                        "a file to commit and continue from with --resume-from")
    p.add_argument("--init-from", type=Path, default=None, metavar="CKPT",
                   help="start from another run's actor and critic: a model_<it>.pt (or a networks-only "
                        "file such as docs/policies/base_networks.pt) or a run directory (its newest); "
                        "not with --resume")
    p.add_argument("--init-std", type=positive_float, default=None, metavar="S",
                   help="with --init-from: set the actor's exploration std to S in every action dimension "
                        "(default: keep the source's)")
    p.add_argument("--run-dir", type=Path, default=None,
                   help="run directory (default: a new <log-root>/<task>/<time>); must be empty unless --resume")
    p.add_argument("--log-root", type=Path, default=Path("runs"))
    p.add_argument("--save-interval", type=positive_int, default=None,
                   help="save every K iterations (default: iterations/10, at most agent.save_interval)")
    p.add_argument("--save-every-min", type=positive_float, default=DEFAULT_SAVE_EVERY_MIN,
                   help=f"also save when this many minutes passed since the last save ({DEFAULT_SAVE_EVERY_MIN})")
    p.add_argument("--time-limit", type=positive_float, default=None, metavar="SECONDS",
                   help="stop cleanly (checkpoint, curve, export; exit 0) before SECONDS of wall time since the "
                        "start; continue with --resume (default: no limit)")
    p.add_argument("--num-workers", type=non_negative_int, default=None,
                   help="simulator worker processes (scene.num_workers; 0 = in-process)")
    p.add_argument("--backend", default=None,
                   help="simulator backend (scene.backend, sim/interface.py): cpu, or cuda with --device cuda for "
                        "MuJoCo Warp on the GPU (the [gpu] extra, docs/gpu.md); default: the task's")
    p.add_argument("--update-threads", type=non_negative_int, default=None,
                   help="torch threads of the PPO update (default: every core, shared among torchrun's processes "
                        "on the machine; the simulator workers idle then; 0: the trainer's own count)")
    p.add_argument("--stock-update", action="store_true",
                   help="rsl-rl's PPO update as shipped, without learning/fast_update.py (same numbers, slower)")
    add_set_argument(p, "recorded in the run's task.yaml")
    return p.parse_args(argv)


def default_save_interval(iterations: int, agent_interval: int) -> int:
    """Ten checkpoints per run, never fewer iterations apart than 1 nor more than ``agent_interval``."""
    return max(1, min(int(agent_interval), iterations // 10))


def _resume_dir(args: argparse.Namespace, task_dir: Path) -> Path:
    run_dir = args.run_dir or latest_run(task_dir)
    if run_dir is None or not run_dir.is_dir():
        raise UserError(f"--resume: no run with a checkpoint under {args.run_dir or task_dir}")
    return run_dir


def _fresh_dir(args: argparse.Namespace, task_dir: Path) -> Path:
    if args.run_dir is None:
        return new_run_dir(task_dir)
    if args.run_dir.exists() and any(args.run_dir.iterdir()):
        raise UserError(f"--run-dir {args.run_dir} is not empty; add --resume to continue it or choose a new one")
    args.run_dir.mkdir(parents=True, exist_ok=True)
    return args.run_dir


def _init_source(path: Path, flag: str = "--init-from") -> tuple[Path, dict]:
    """The checkpoint ``flag`` names (a file, or a run directory's newest readable one)."""
    if path.is_dir():
        found = newest_readable_checkpoint(path)
        if found is None:
            raise UserError(f"{flag}: no readable model_<it>.pt in {path}")
        return found
    if not path.is_file():
        raise UserError(f"{flag}: {path} does not exist (give a model_<it>.pt or a run directory)")
    try:
        return path, read_checkpoint(path)
    except ValueError as err:
        raise UserError(f"{flag}: cannot read {path}: {err}") from None


def _checkpoint_seed(ckpt: dict) -> int | None:
    """The env seed a checkpoint was trained with (its episode schedule's), None if it does not say."""
    schedule = ckpt.get("env_state", {}).get("schedule")
    return None if schedule is None else int(schedule["seed"])


def _choose_run(args: argparse.Namespace, task_dir: Path) -> tuple[Path, tuple[Path, dict] | None]:
    """The run directory (created if fresh) and, with ``--resume``, its newest readable checkpoint
    (with ``--resume-from``, that file)."""
    if args.resume_from is not None:
        found = _init_source(args.resume_from, "--resume-from")  # read before a run directory is made
        _choose_seed(args, found)
        return _fresh_dir(args, task_dir), found
    if not args.resume:
        return _fresh_dir(args, task_dir), None
    run_dir = _resume_dir(args, task_dir)
    found = newest_readable_checkpoint(run_dir)
    if found is None:
        raise UserError(f"--resume: no readable checkpoint in {run_dir}")
    return run_dir, found


def _agree_on_run(args: argparse.Namespace, task_dir: Path, ranks: Ranks) -> tuple[Path, tuple[Path, dict] | None]:
    """``_choose_run`` on rank 0, its answer (or its user error) on every rank.

    Only rank 0 looks at and creates directories, so N processes started in the same second
    share one new run directory instead of making N; the others read the checkpoint rank 0 chose.
    """
    if not ranks.is_distributed:
        return _choose_run(args, task_dir)
    choice: tuple[str, str | None] | str
    if ranks.is_main:
        try:
            run_dir, found = _choose_run(args, task_dir)
            choice = (str(run_dir), str(found[0]) if found else None)
        except UserError as err:
            choice = str(err)
            broadcast_from_main(choice, ranks)  # the others must not wait for an answer that never comes
            raise
    else:
        choice = None
    choice = broadcast_from_main(choice, ranks)
    if isinstance(choice, str):
        raise UserError(choice)
    run_dir, ckpt_path = Path(choice[0]), choice[1]
    if ranks.is_main:
        return run_dir, found
    return run_dir, ((Path(ckpt_path), read_checkpoint(Path(ckpt_path))) if ckpt_path else None)


def _choose_seed(args: argparse.Namespace, found: tuple[Path, dict] | None) -> int:
    """``--seed``, or the checkpoint's when continuing one; a different explicit ``--seed`` is refused
    (the env's per-robot randomisation at startup follows the seed, so the run would not continue)."""
    saved = _checkpoint_seed(found[1]) if found is not None else None
    if saved is None:
        return args.seed if args.seed is not None else 0
    if args.seed is not None and args.seed != saved:
        raise UserError(f"--seed {args.seed}: {found[0]} was trained with seed {saved}; "
                        f"give --seed {saved} or leave --seed out")
    return saved


def checkpoint_num_envs(ckpt: dict) -> int | None:
    """The number of robots a checkpoint's episodes in progress were saved with (None: it does not say, and
    the task's ``env.num_envs`` applies). A continued run keeps it unless ``--num-envs`` says otherwise."""
    episodes = (ckpt.get("env_state") or {}).get("episodes") or {}
    n = episodes.get("num_envs")
    return int(n) if n is not None else None


def main(argv: list[str] | None = None) -> Path:
    """Train; returns the run directory."""
    args = parse_args(argv)
    args.deadline = Deadline(args.time_limit) if args.time_limit is not None else None
    if args.device == "cuda" and "LOCAL_RANK" in os.environ:  # torchrun: one GPU per process
        args.device = f"cuda:{os.environ['LOCAL_RANK']}"
    ranks = init_distributed(args.device)  # torchrun: join the group before any rank touches the run dir
    try:
        return _train(args, ranks)
    finally:
        if ranks.is_distributed:
            close_distributed()


def _train(args: argparse.Namespace, ranks: Ranks) -> Path:
    scene = {k: v for k, v in (("num_workers", args.num_workers), ("backend", args.backend)) if v is not None}
    task = load_task(args.task, overrides=merge_overrides({"scene": scene} if scene else None, set_overrides(args.set)))
    if args.init_from is not None and args.resume:
        raise UserError("--init-from starts a new run and --resume continues one; give only one of them")
    if args.resume_from is not None and (args.resume or args.init_from is not None):
        raise UserError("--resume-from continues from a checkpoint file in a new run directory; "
                        "give it without --resume and --init-from")
    if args.init_std is not None and args.init_from is None:
        raise UserError("--init-std sets the exploration std of an --init-from start; give --init-from too")
    source = _init_source(args.init_from) if args.init_from is not None else None
    task_dir = args.log_root / task.name
    cfg = runner_config(task.data["agent"], args.iterations, args.seed if args.seed is not None else 0)
    cfg["save_interval"] = args.save_interval or default_save_interval(int(cfg["max_iterations"]),
                                                                       cfg.get("save_interval", 50))
    run_dir, found = _agree_on_run(args, task_dir, ranks)
    base_seed = _choose_seed(args, found)
    cfg["seed"] = base_seed
    seed = base_seed + ranks.rank  # other robots' rollouts on every rank; rank 0's weights win (broadcast)
    torch.manual_seed(seed)
    num_envs = args.num_envs if args.num_envs is not None or found is None else checkpoint_num_envs(found[1])
    env = LocomotionEnv(task, num_envs=num_envs, device=args.device, seed=seed)
    try:
        runner = AtomicOnPolicyRunner(env, cfg, log_dir=str(run_dir), device=args.device,
                                      save_every_s=60.0 * args.save_every_min,
                                      fast_update=not args.stock_update, update_threads=args.update_threads,
                                      deadline=args.deadline)
        runner.copy_to = str(args.checkpoint_copy) if args.checkpoint_copy is not None and ranks.is_main else None
        if found is not None:
            path, ckpt = found
            try:
                runner.load_checkpoint(ckpt, str(path))  # checked against the task before anything is written
            except CheckpointMismatch as err:
                raise UserError(f"{'--resume-from' if args.resume_from is not None else '--resume'}: {err}") from None
            for change in resume_state.changes(ckpt, runner):
                print(f"[train] note: {change} differs from the checkpoint's: the run goes on, "
                      "but not exactly as the uninterrupted one", flush=True)
            # model_<it>.pt holds the state after iteration <it>: continue with the next one
            runner.current_learning_iteration += 1
            if ranks.rank > 0:  # the checkpoint holds rank 0's RNG: give this rank its own stream again
                torch.manual_seed(int(torch.randint(2**62, (1,))) + ranks.rank)
            restored = "env state restored" if "env_state" in ckpt else "no env state in it: curricula start afresh"
            print(f"[train] resumed from {path} at iteration {runner.current_learning_iteration} ({restored}; "
                  f"curriculum {env.curriculum_manager.values_as_floats()})", flush=True)
        elif source is not None:
            path, ckpt = source
            try:
                runner.init_networks(ckpt, str(path))
            except CheckpointMismatch as err:
                raise UserError(f"--init-from: {err}") from None
            if args.init_std is not None:
                runner.set_action_std(args.init_std)
            print(f"[train] initialised actor and critic from {path} (its iteration {ckpt['iter']}; action std "
                  f"{'set to ' + str(args.init_std) if args.init_std is not None else 'kept'}); "
                  f"optimiser, iteration and env state start afresh (curriculum "
                  f"{env.curriculum_manager.values_as_floats()}); normalisers go on from its statistics", flush=True)
            if ranks.is_main:
                write_yaml({"init_from": str(path), "iteration": int(ckpt["iter"]),
                            "sha256": sha256_file(path), "init_std": args.init_std}, run_dir / "init_from.yaml")
        if ranks.is_main and args.resume_from is not None:
            write_yaml({"resumed_from": str(found[0]), "iteration": int(found[1]["iter"]),
                        "sha256": sha256_file(found[0])}, run_dir / "resumed_from.yaml")
        if ranks.is_main:
            for stale in remove_stale_tmp(run_dir):
                print(f"[train] note: removed {stale} (left by a save that was killed)")
            save_resolved(task, run_dir / "task.yaml")
            write_yaml(cfg, run_dir / "agent.yaml")
        previous = runner.install_signal_handlers()
        try:
            runner.learn(int(cfg["max_iterations"]), init_at_random_ep_len=found is None)
        except TrainingInterrupted as stop:
            print(f"[train] stopped by {signal.Signals(stop.signum).name}; "
                  + (f"saved {stop.path}; continue with --resume --run-dir {run_dir}" if stop.path
                     else "no iteration had finished, nothing saved"), flush=True)
            raise SystemExit(128 + stop.signum) from None
        except TimeLimitReached as stop:
            print(f"[train] time limit ({args.time_limit:g} s) reached after iteration {stop.iteration} "
                  f"({args.deadline.left():.0f} s left); saved {stop.path}; continue with --resume --run-dir "
                  f"{run_dir}", flush=True)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
        if ranks.is_main:
            exported = export_policy(runner, run_dir / "exported")
            print(f"[train] run dir {run_dir}; exported {exported}")
    finally:
        env.close()
    return run_dir


if __name__ == "__main__":
    run_cli(main)
