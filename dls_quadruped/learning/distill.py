"""Distil an RL expert into a horizon student (thesis 5.2): naive imitation or DAgger.

    python -m dls_quadruped.learning.distill                       # tasks/agents/distill.yaml (Table 7)
    python -m dls_quadruped.learning.distill --encoding first-spline --horizon 10 --dt 0.02 \\
        --algo dagger --epochs 5 --datapoints-per-epoch 4000 --run-dir runs/distill/small
    python -m dls_quadruped.learning.distill --resume --run-dir runs/distill/small

A run directory holds ``distill.yaml`` (the resolved settings), ``dataset/`` and ``test/``
(disk-backed datasets), ``checkpoint.pt`` (after every epoch, atomic), TensorBoard events,
``metrics.json``, ``mse_sp.png`` and ``exported/student.pt2`` (a ``torch.export`` program) with
``exported/student.json`` (encoding metadata, also inside the archive). ``--resume`` continues
the newest run (or ``--run-dir``) after its last finished epoch; rows collected since are kept.
See docs/distill.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import yaml

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
)
from dls_quadruped.core.json_io import write_json
from dls_quadruped.envs.config import load_task
from dls_quadruped.learning import checkpoint_file
from dls_quadruped.learning.checkpoint_file import UnsafeCheckpoint
from dls_quadruped.learning.dataset import DatasetError
from dls_quadruped.learning.distill_config import (
    ALGORITHMS,
    DEFAULT_CONFIG,
    NAIVE_SCHEDULES,
    SELECTORS,
    load_distill_config,
)
from dls_quadruped.learning.distill_trainer import CHECKPOINT, DistillTrainer
from dls_quadruped.learning.policy_file import load_module
from dls_quadruped.learning.runner import new_run_dir, sha256_file
from dls_quadruped.mpc.config import ENCODING_KINDS

RESOLVED = "distill.yaml"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=None, help=f"distillation YAML (default {DEFAULT_CONFIG.name}; "
                   f"on --resume the run's own {RESOLVED})")
    p.add_argument("--task", default=None, help="env task name or YAML path (default: the config's, base)")
    p.add_argument("--expert", default=None,
                   help="exported expert actor, .pt2 or TorchScript .pt (default: the config's)")
    p.add_argument("--encoding", default=None, help="<p>-<F>, each discrete|spline|first, e.g. first-spline")
    p.add_argument("--horizon", type=int, default=None, help="H, actions in the horizon (>= 1; >= 4 with a spline)")
    p.add_argument("--dt", type=positive_float, default=None, help="[s] spacing of the H actions (multiple of 0.02)")
    p.add_argument("--algo", choices=ALGORITHMS, default=None)
    p.add_argument("--selector", choices=SELECTORS, default=None, help="DAgger beta(i)")
    p.add_argument("--alpha", type=positive_float, default=None, help="beta(i) = alpha^i")
    p.add_argument("--epochs", type=positive_int, default=None)
    p.add_argument("--datapoints-per-epoch", type=positive_int, default=None)
    p.add_argument("--dataset-cap", type=positive_int, default=None)
    p.add_argument("--batch-size", type=positive_int, default=None)
    p.add_argument("--naive-schedule", choices=NAIVE_SCHEDULES, default=None,
                   help="naive: full (every epoch on all data) or dagger_steps (DAgger's gradient steps)")
    p.add_argument("--num-envs", type=positive_int, default=None)
    p.add_argument("--num-workers", type=non_negative_int, default=None, help="simulator processes (0: in-process)")
    p.add_argument("--test-datapoints", type=positive_int, default=None)
    p.add_argument("--test-episodes", type=positive_int, default=None,
                   help="whole expert episodes the test windows are cut from")
    p.add_argument("--sp-episodes", type=positive_int, default=None)
    p.add_argument("--sp-every", type=non_negative_int, default=None, help="SP every k epochs (0: last only)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--run-dir", type=Path, default=None, help="default: a new runs/distill/<time>")
    p.add_argument("--log-root", type=Path, default=Path("runs") / "distill")
    p.add_argument("--resume", action="store_true",
                   help="continue after the last finished epoch, with the run's stored settings (flags given "
                        "override them)")
    p.add_argument("--out", type=Path, default=None,
                   help="also copy student.pt2/.json, metrics.json and mse_sp.png here")
    return p.parse_args(argv)


def overrides_from_args(args: argparse.Namespace) -> dict:
    """Nested config overrides for the flags that were given."""
    over: dict = {}

    def put(section: str | None, key: str, value) -> None:
        if value is not None:
            (over.setdefault(section, {}) if section else over)[key] = value

    if args.encoding is not None:
        parts = args.encoding.split("-")
        if len(parts) != 2 or any(k not in ENCODING_KINDS for k in parts):
            raise UserError(f"--encoding {args.encoding!r}: unknown encoding; allowed: <p>-<F> with each of "
                            f"{'|'.join(ENCODING_KINDS)}, e.g. first-spline")
        put("encoding", "p", parts[0])
        put("encoding", "F", parts[1])
    put("encoding", "horizon", args.horizon)
    put("encoding", "dt", args.dt)
    put(None, "expert", args.expert)
    put(None, "task", args.task)
    put(None, "algorithm", args.algo)
    put("selector", "kind", args.selector)
    put("selector", "alpha", args.alpha)
    for key in ("epochs", "datapoints_per_epoch", "dataset_cap", "batch_size", "seed", "naive_schedule"):
        put("train", key, getattr(args, key))
    put("collect", "num_envs", args.num_envs)
    put("collect", "num_workers", args.num_workers)
    for key in ("test_datapoints", "test_episodes", "sp_episodes", "sp_every"):
        put("evaluate", key, getattr(args, key))
    return over


def load_expert(path: str | Path) -> torch.nn.Module:
    """The exported expert actor, a program or TorchScript (checked for size against the env by
    :func:`check_expert`)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"expert {path} not found (an exported actor such as docs/policies/base_actor.pt or "
                        "runs/<task>/<run>/exported/policy.pt2)")
    try:
        return load_module(path)
    except (RuntimeError, ValueError) as err:
        raise UserError(f"expert {path}: not a .pt2 program, not a TorchScript actor "
                        f"({str(err).splitlines()[0][:120]}); export one with `make train` "
                        "(exported/policy.pt2)") from None


def check_expert(expert, path: str | Path, obs_dim: int, num_actions: int) -> None:
    """Refuse an expert whose observation or action size is not the task's."""
    first = next((p for p in expert.parameters() if p.dim() == 2), None)
    if first is not None and first.shape[1] != obs_dim:
        raise UserError(f"expert {path} takes {first.shape[1]} observations; the task gives {obs_dim}")
    try:
        with torch.no_grad():
            out = expert(torch.zeros(2, obs_dim))
    except RuntimeError as err:
        raise UserError(f"expert {path} does not accept {obs_dim} observations: {str(err).splitlines()[0][:160]}") \
            from None
    if tuple(out.shape) != (2, num_actions):
        raise UserError(f"expert {path} outputs {tuple(out.shape[1:])} actions per robot; the task needs {num_actions}")


def distill_task(task: str, num_workers: int | None, overrides: dict | None = None):
    """The expert's task without curricula (fixed, full reward weights), 15 s episodes; ``overrides``: task
    sections changed on top (e.g. an experiment's narrower commands or added noise)."""
    from dls_quadruped.envs.sections import replace_sections

    over = dict(overrides or {})
    if num_workers is not None:
        over["scene"] = {**over.get("scene", {}), "num_workers": num_workers}
    cfg = load_task(task, overrides=over or None)
    return replace_sections(cfg, {"curriculum": {}}, source="<distill: no curriculum>")


def _flat_keys(over: dict, prefix: str = "") -> list[str]:
    """Dotted keys of a nested override dict (``{"train": {"epochs": 2}}`` -> ``["train.epochs"]``)."""
    keys = []
    for key, value in over.items():
        keys += _flat_keys(value, f"{prefix}{key}.") if isinstance(value, dict) else [f"{prefix}{key}"]
    return keys


def resume_summary(run_dir: Path, cfg, over: dict) -> str:
    """One line saying what a resumed run continues with: its stored settings (``<run>/distill.yaml``), and
    which of them the command line overrode."""
    enc = cfg.encoding
    given = _flat_keys(over)
    return (f"[distill] resuming {run_dir} with its stored settings: expert {cfg.expert}, {cfg.algorithm}, "
            f"{enc.p}-{enc.F} H={enc.horizon} dt={enc.dt:g}, {cfg.train.epochs} epochs; "
            + (f"overridden on the command line: {', '.join(given)}" if given else "nothing overridden"))


def _run_dir(args: argparse.Namespace) -> Path | None:
    """The run directory to continue (--resume), or the --run-dir to create (checked empty), or None
    (a new one under --log-root). Nothing is created here."""
    if args.resume:
        run_dir = args.run_dir
        if run_dir is None:
            runs = sorted(args.log_root.glob(f"*/{CHECKPOINT}"), key=lambda p: p.stat().st_mtime)
            run_dir = runs[-1].parent if runs else None
        if run_dir is None or not (run_dir / CHECKPOINT).is_file():
            raise UserError(f"--resume: no {CHECKPOINT} under {args.run_dir or args.log_root}")
        return run_dir
    if args.run_dir is not None and args.run_dir.exists() and any(args.run_dir.iterdir()):
        raise UserError(f"--run-dir {args.run_dir} is not empty; add --resume to continue it or choose a new one")
    return args.run_dir


def _read_checkpoint(run_dir: Path) -> dict:
    path = run_dir / CHECKPOINT
    try:
        state = checkpoint_file.load(path)
    except UnsafeCheckpoint as err:
        raise UserError(f"--resume: {path} is {err}") from None
    except Exception as err:  # noqa: BLE001 -- any unpickling failure means unreadable
        raise UserError(f"--resume: {path} is unreadable ({type(err).__name__}); the datasets in {run_dir} are "
                        "kept: start a new run with --run-dir elsewhere") from None
    if not isinstance(state, dict) or "student" not in state:
        raise UserError(f"--resume: {path} is not a distillation checkpoint")
    return state


def write_outputs(trainer: DistillTrainer, run_dir: Path, out: Path | None) -> dict:
    """metrics.json, mse_sp.png and the export."""
    exported = trainer.export(run_dir / "exported")
    final = trainer.history[-1] if trainer.history else {}
    metrics = {"config": trainer.cfg.to_dict(), "expert": trainer.expert_info, "encoding": trainer.meta,
               "final": {k: final.get(k) for k in ("epoch", "test_mse", "sp", "dataset_size")},
               "sp_reference": None if trainer.reference is None else {
                   k: {"mean_return": float(v["return"].mean()), "episodes": len(v["return"])}
                   for k, v in trainer.reference.items() if isinstance(v, dict)},
               "history": trainer.history, "export": str(exported)}
    write_json(metrics, run_dir / "metrics.json")
    from dls_quadruped.learning.distill_plot import plot_history

    plot_history(trainer.history, run_dir / "mse_sp.png", title=f"{trainer.cfg.algorithm} "
                 f"{trainer.enc.p}-{trainer.enc.F} H={trainer.enc.horizon} dt={trainer.cfg.encoding.dt:g}")
    if out is not None:
        import shutil

        out.mkdir(parents=True, exist_ok=True)
        for f in (exported, exported.with_suffix(".json"), run_dir / "metrics.json", run_dir / "mse_sp.png"):
            shutil.copy2(f, out / f.name)
    return metrics


def main(argv: list[str] | None = None) -> Path:
    """Run (or continue) a distillation; returns the run directory."""
    from torch.utils.tensorboard import SummaryWriter

    from dls_quadruped.envs.env import LocomotionEnv

    args = parse_args(argv)
    over = overrides_from_args(args)
    config_path = args.config
    if args.resume and config_path is None and args.run_dir is not None and (args.run_dir / RESOLVED).is_file():
        config_path = args.run_dir / RESOLVED
    cfg = load_distill_config(config_path, over)
    run_dir = _run_dir(args)
    state = None
    if args.resume:
        if args.config is None and (run_dir / RESOLVED).is_file():
            cfg = load_distill_config(run_dir / RESOLVED, over)
        state = _read_checkpoint(run_dir)
        if state["config"]["encoding"] != cfg.to_dict()["encoding"] or state["config"]["algorithm"] != cfg.algorithm:
            raise UserError(f"--resume: {run_dir} was started with {state['config']['algorithm']} "
                            f"{state['config']['encoding']}, not {cfg.algorithm} {cfg.to_dict()['encoding']}")
        print(resume_summary(run_dir, cfg, over), flush=True)
    expert = load_expert(cfg.expert)  # the run's own expert on --resume, unless --expert names another
    task = distill_task(cfg.task, cfg.collect.num_workers)
    torch.manual_seed(cfg.train.seed)
    env = LocomotionEnv(task, num_envs=cfg.collect.num_envs, seed=cfg.train.seed, verbose=False)
    try:
        obs_dim = int(env.get_observations()["policy"].shape[1])
        check_expert(expert, cfg.expert, obs_dim, env.num_actions)
        try:
            cfg.encoding.stride(env.step_dt)
        except ValueError as err:
            raise UserError(str(err)) from None
        agent_actor = task.data.get("agent", {}).get("actor", {})
        if run_dir is None:  # created only now that every input was checked
            run_dir = new_run_dir(args.log_root)
        run_dir.mkdir(parents=True, exist_ok=True)
        hidden = list(cfg.student.hidden_dims or agent_actor.get("hidden_dims", [512, 256, 128]))
        activation = cfg.student.activation or agent_actor.get("activation", "elu")
        info = {"path": str(cfg.expert), "sha256": sha256_file(Path(cfg.expert))}
        if state is not None and state.get("expert", {}).get("sha256") not in (None, info["sha256"]):
            raise UserError(f"--resume: expert {cfg.expert} changed since {run_dir} started (sha256 "
                            f"{state['expert']['sha256'][:12]}..., now {info['sha256'][:12]}...); its labels "
                            "would mix two experts: start a new run")
        trainer = DistillTrainer(cfg, env, expert, run_dir, hidden, activation, expert_info=info)
        if state is not None:
            trainer.load_state_dict(state)
            print(f"[distill] resumed {run_dir} after epoch {trainer.epoch}/{cfg.train.epochs}", flush=True)
        try:
            trainer.open_datasets(resume=state is not None)
        except DatasetError as err:
            raise UserError(str(err)) from None
        for stale in run_dir.glob("*.tmp"):
            stale.unlink()
        (run_dir / RESOLVED).write_text(f"# resolved distillation settings (from {cfg.path})\n"
                                        + yaml.safe_dump(cfg.to_dict(), sort_keys=False))
        trainer.writer = SummaryWriter(log_dir=str(run_dir))
        print(f"[distill] run dir {run_dir}: {cfg.algorithm}, {trainer.enc.p}-{trainer.enc.F}, "
              f"H={trainer.enc.horizon}, "
              f"dt={cfg.encoding.dt:g} s (every {trainer.stride} env steps), output {trainer.meta['output_dim']}, "
              f"{env.num_envs} envs, expert {cfg.expert}", flush=True)
        trainer.collect_test_set()
        trainer.reference_returns()
        trainer.save()
        while trainer.epoch < cfg.train.epochs:
            trainer.run_epoch()
        trainer.writer.close()
        metrics = write_outputs(trainer, run_dir, args.out)
        print(f"[distill] done: test MSE {metrics['final']['test_mse']:.4f}; exported {metrics['export']}", flush=True)
    finally:
        env.close()
    return run_dir


if __name__ == "__main__":
    run_cli(main)
