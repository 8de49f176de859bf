"""Re-export an exported actor (``exported/policy.pt2``, a TorchScript ``docs/policies/*.pt``) to ONNX
or to a ``torch.export`` program, checked numerically; or export any training checkpoint's actor
(program + ONNX, as training does at its end).

    python -m dls_quadruped.learning.export docs/policies/base_actor.pt docs/policies/base_actor.onnx --task base
    python -m dls_quadruped.learning.export docs/policies/base_actor.pt base_actor.pt2 --task base
    python -m dls_quadruped.learning.export --checkpoint runs/speed/<run>/model_300.pt --task speed --out-dir DIR

The actor is rebuilt from the task's ``agent.actor`` config (the same rsl-rl ``MLPModel`` training
makes), the exported weights are loaded into it (every normaliser and MLP tensor must match), and
``policy_export.export_actor_onnx`` or ``policy_export.export_actor_program`` writes it with a free batch size, as
training does; the output's suffix (``.onnx``, ``.pt2``) says which. The new file is then run (ONNX
with onnxruntime) on in-distribution observations (normaliser mean + std x N(0, 1)) and compared with
the source actor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning.policy_export import (
    export_actor_onnx,
    export_actor_program,
    export_policy,
)
from dls_quadruped.learning.policy_file import PROGRAM_SUFFIX, load_module
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    CheckpointMismatch,
    read_checkpoint,
    runner_config,
)

ONNX_ATOL = 1e-5
"""Largest |exported - source| action accepted when a re-export is checked."""
EXPORTERS = {".onnx": export_actor_onnx, PROGRAM_SUFFIX: export_actor_program}
"""Output suffix -> writer of an rsl-rl actor."""


def typical_observations(actor: torch.nn.Module, batch: int, seed: int = 0) -> torch.Tensor:
    """(batch, obs_dim) observations as an exported actor saw them in training: its normaliser's
    mean + std x N(0, 1)."""
    state = actor.state_dict()
    mean, std = state["obs_normalizer._mean"], state["obs_normalizer._std"]  # (1, obs_dim) each
    gen = torch.Generator().manual_seed(seed)
    return mean + std * torch.randn(batch, mean.shape[-1], generator=gen)


def onnx_error(onnx_path: Path, actor: torch.nn.Module, batch: int, seed: int = 0) -> float:
    """Max |ONNX - actor| over ``batch`` typical observations (onnxruntime, CPU)."""
    import onnxruntime as ort

    obs = typical_observations(actor, batch, seed)
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    got = sess.run(None, {sess.get_inputs()[0].name: obs.numpy()})[0]
    with torch.no_grad():
        expected = actor(obs).numpy()
    return float(np.abs(got - expected).max())


def export_error(path: Path, actor: torch.nn.Module, batch: int, seed: int = 0) -> float:
    """Max |exported - actor| over ``batch`` typical observations: ONNX through onnxruntime, a program
    through torch."""
    if Path(path).suffix == ".onnx":
        return onnx_error(path, actor, batch, seed)
    obs = typical_observations(actor, batch, seed)
    with torch.no_grad():
        return float((load_module(path)(obs) - actor(obs)).abs().max())


def load_actor(path: Path) -> torch.nn.Module:
    """An exported actor (program or TorchScript) on the CPU, or a ``UserError`` saying what ``path`` is."""
    try:
        return load_module(path)
    except ValueError as err:
        raise UserError(str(err)) from None


def reexport(source: Path, out: Path, task_name: str) -> Path:
    """Rebuild ``task_name``'s actor, load the exported actor ``source``'s weights into it and write it to
    ``out`` (``.onnx`` or ``.pt2``, :data:`EXPORTERS`).

    Raises:
        UserError: an output suffix without an exporter, or weights that do not fit the task's actor.
    """
    if out.suffix not in EXPORTERS:
        raise UserError(f"{out}: the output is a {' or a '.join(EXPORTERS)} file")
    exported = load_actor(source)
    task = load_task(task_name, overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=1, verbose=False)
    try:
        actor = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None).alg.get_policy()
        try:
            missing, unexpected = actor.load_state_dict(exported.state_dict(), strict=False)
        except RuntimeError as err:
            raise UserError(f"{source} does not fit task {task_name}'s actor: {str(err).splitlines()[0]}") from None
        # the action noise (distribution.*) is not part of the deterministic exported actor
        if unexpected or any(not k.startswith("distribution.") for k in missing):
            raise UserError(f"{source} does not fit task {task_name}'s actor: missing {missing}, "
                            f"unexpected {unexpected}")
        return EXPORTERS[out.suffix](actor.eval(), out)
    finally:
        env.close()


def checkpoint_to_policy(ckpt_path: Path, out_dir: Path, task_name: str) -> dict[str, Path | str]:
    """Export the deterministic actor of a training checkpoint (``model_<it>.pt``) to
    ``out_dir/policy.pt2`` (a ``torch.export`` program) and ``out_dir/policy.onnx``, as training does at its end.

    Raises:
        UserError: the file is not a checkpoint, or its networks do not fit the task's.
    """
    try:
        ckpt = read_checkpoint(ckpt_path)
    except ValueError as err:
        raise UserError(f"--checkpoint: cannot read {ckpt_path}: {err}") from None
    task = load_task(task_name, overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=1, verbose=False)
    try:
        runner = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None)
        try:
            runner.init_networks(ckpt, str(ckpt_path))
        except CheckpointMismatch as err:
            raise UserError(f"--checkpoint: {err}") from None
        return export_policy(runner, out_dir)
    finally:
        env.close()


def main(argv: list[str] | None = None) -> Path:
    p = ArgumentParser(description=__doc__)
    p.add_argument("source", type=Path, nargs="?", help="exported actor to re-export (.pt2 program or TorchScript .pt)")
    p.add_argument("out", type=Path, nargs="?", help="file to write: .onnx or .pt2")
    p.add_argument("--task", default="base", help="task whose agent.actor built the policy")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="instead: export this training checkpoint's actor to --out-dir")
    p.add_argument("--out-dir", type=Path, default=None, help="with --checkpoint: where policy.pt2/.onnx go")
    args = p.parse_args(argv)
    if args.checkpoint is not None:
        if args.source is not None or args.out_dir is None:
            raise UserError("--checkpoint exports to --out-dir; give --checkpoint CKPT --out-dir DIR and no "
                            "positional files")
        exported = checkpoint_to_policy(args.checkpoint, args.out_dir, args.task)
        print(f"[export] {args.checkpoint} -> {exported}")
        return Path(exported["program"])
    if args.source is None or args.out is None:
        raise UserError("give SOURCE OUT (re-export to .onnx or .pt2) or --checkpoint CKPT --out-dir DIR")
    if not args.source.is_file():
        raise UserError(f"{args.source}: no such file")
    out = reexport(args.source, args.out, args.task)
    source = load_actor(args.source)
    errors = {b: export_error(out, source, b) for b in (1, 64)}
    print(f"[export] {out}: max |{out.suffix} - {args.source.name}| {errors} (batch: error)")
    if max(errors.values()) > ONNX_ATOL:
        raise SystemExit(f"{out} differs from {args.source} by more than {ONNX_ATOL}")
    return out


if __name__ == "__main__":
    run_cli(main)
