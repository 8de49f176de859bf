"""Re-export a TorchScript actor (``exported/policy.pt``, ``docs/policies/*.pt``) to ONNX, checked
numerically; or export any training checkpoint's actor (TorchScript + ONNX, as training does at its end).

    python -m dls_quadruped.learning.export docs/policies/base_actor.pt docs/policies/base_actor.onnx --task base
    python -m dls_quadruped.learning.export --checkpoint runs/speed/<run>/model_300.pt --task speed --out-dir DIR

The actor is rebuilt from the task's ``agent.actor`` config (the same rsl-rl ``MLPModel`` training
makes), the TorchScript weights are loaded into it (every normaliser and MLP tensor must match), and
``runner.export_actor_onnx`` writes it with a free batch size, as training does. The ONNX file is then
run with onnxruntime on in-distribution observations (normaliser mean + std x N(0, 1)) and compared
with the TorchScript actor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    CheckpointMismatch,
    export_actor_onnx,
    export_policy,
    read_checkpoint,
    runner_config,
)

ONNX_ATOL = 1e-5


def typical_observations(jit_actor: torch.jit.ScriptModule, batch: int, seed: int = 0) -> torch.Tensor:
    """(batch, obs_dim) observations as the actor saw them in training: its normaliser's mean + std x N(0, 1)."""
    norm = jit_actor.obs_normalizer
    gen = torch.Generator().manual_seed(seed)
    return norm._mean + norm._std * torch.randn(batch, norm._mean.shape[-1], generator=gen)


def onnx_error(onnx_path: Path, jit_actor: torch.jit.ScriptModule, batch: int, seed: int = 0) -> float:
    """Max |ONNX - TorchScript| over ``batch`` typical observations (onnxruntime, CPU)."""
    import onnxruntime as ort

    obs = typical_observations(jit_actor, batch, seed)
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    got = sess.run(None, {sess.get_inputs()[0].name: obs.numpy()})[0]
    with torch.no_grad():
        expected = jit_actor(obs).numpy()
    return float(np.abs(got - expected).max())


def torchscript_to_onnx(jit_path: Path, onnx_path: Path, task_name: str) -> Path:
    """Rebuild ``task_name``'s actor, load ``jit_path``'s weights into it and export it to ``onnx_path``.

    Raises:
        UserError: the TorchScript weights do not fit the task's actor.
    """
    jit_actor = torch.jit.load(str(jit_path), map_location="cpu").eval()
    task = load_task(task_name, overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=1, verbose=False)
    try:
        actor = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None).alg.get_policy()
        try:
            missing, unexpected = actor.load_state_dict(jit_actor.state_dict(), strict=False)
        except RuntimeError as err:
            raise UserError(f"{jit_path} does not fit task {task_name}'s actor: {str(err).splitlines()[0]}") from None
        # the action noise (distribution.*) is not part of the deterministic TorchScript actor
        if unexpected or any(not k.startswith("distribution.") for k in missing):
            raise UserError(f"{jit_path} does not fit task {task_name}'s actor: missing {missing}, "
                            f"unexpected {unexpected}")
        return export_actor_onnx(actor.eval(), onnx_path)
    finally:
        env.close()


def checkpoint_to_policy(ckpt_path: Path, out_dir: Path, task_name: str) -> dict[str, Path | str]:
    """Export the deterministic actor of a training checkpoint (``model_<it>.pt``) to
    ``out_dir/policy.pt`` (TorchScript) and ``out_dir/policy.onnx``, as training does at its end.

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
    p.add_argument("torchscript", type=Path, nargs="?", help="TorchScript actor to re-export")
    p.add_argument("onnx", type=Path, nargs="?", help="ONNX file to write")
    p.add_argument("--task", default="base", help="task whose agent.actor built the policy")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="instead: export this training checkpoint's actor to --out-dir")
    p.add_argument("--out-dir", type=Path, default=None, help="with --checkpoint: where policy.pt/.onnx go")
    args = p.parse_args(argv)
    if args.checkpoint is not None:
        if args.torchscript is not None or args.out_dir is None:
            raise UserError("--checkpoint exports to --out-dir; give --checkpoint CKPT --out-dir DIR and no positional files")
        exported = checkpoint_to_policy(args.checkpoint, args.out_dir, args.task)
        print(f"[export] {args.checkpoint} -> {exported}")
        return Path(exported["jit"])
    if args.torchscript is None or args.onnx is None:
        raise UserError("give TORCHSCRIPT ONNX (re-export) or --checkpoint CKPT --out-dir DIR")
    if not args.torchscript.is_file():
        raise UserError(f"{args.torchscript}: no such file")
    out = torchscript_to_onnx(args.torchscript, args.onnx, args.task)
    jit_actor = torch.jit.load(str(args.torchscript), map_location="cpu").eval()
    errors = {b: onnx_error(out, jit_actor, b) for b in (1, 64)}
    print(f"[export] {out}: max |ONNX - TorchScript| {errors} (batch: error)")
    if max(errors.values()) > ONNX_ATOL:
        raise SystemExit(f"ONNX export differs from {args.torchscript} by more than {ONNX_ATOL}")
    return out


if __name__ == "__main__":
    run_cli(main)
