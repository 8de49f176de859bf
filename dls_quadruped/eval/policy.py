"""Load a policy to evaluate: an exported actor or an rsl-rl checkpoint.

* exported actor (``exported/policy.pt2``, a ``torch.export`` program, or a TorchScript one such as
  ``docs/policies/base_actor.pt``; ``learning/policy_file.py``): the actor with its observation
  normaliser, input the actor's observation group(s) concatenated, output the raw action mean;
* checkpoint (``runs/<task>/<run>/model_<it>.pt``): rebuilt through rsl-rl's runner with the run's
  ``agent.yaml`` (next to the checkpoint) or else the task's ``agent`` section, deterministic
  inference policy; the checkpoint's env state (terrain levels, curriculum) is not loaded.

A policy that does not fit the env (another observation size or action size, an unreadable file)
raises ``cli.UserError`` naming the file, what it expects and what the env gives, before any
episode runs.
"""

from __future__ import annotations

from pathlib import Path

import torch
import yaml
from tensordict import TensorDict

from dls_quadruped.cli import UserError
from dls_quadruped.eval.rollout import Policy
from dls_quadruped.learning.policy_file import file_kind, load_module


def check_policy_file(path: str | Path) -> Path:
    """``path`` as a Path if it is a file; else a ``UserError`` that says what is expected."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"policy {path} not found (--policy: an exported actor .pt2 or .pt, e.g. "
                        "docs/policies/base_actor.pt, or a runs/<task>/<run>/model_<it>.pt checkpoint)")
    return path


def input_size(module: torch.nn.Module) -> int | None:
    """Input width of an exported actor: a program's own (``ExportedModule.input_size``), else the last
    dimension of its first 2-D parameter or buffer (the normaliser's mean (1, D) or the first layer's
    weight (H, D)); None if it has none."""
    if isinstance(getattr(module, "input_size", None), int):
        return module.input_size
    for _, tensor in (*module.named_buffers(), *module.named_parameters()):
        if tensor.dim() == 2:
            return int(tensor.shape[-1])
    return None


def load_policy(path: str | Path, env, agent: dict | None = None, flag: str = "--policy",
                same_task: bool = False) -> Policy:
    """A deterministic policy ``obs TensorDict -> (B, A) actions`` for ``env``, checked on the
    env's current observation.

    Args:
        path: exported actor (program or TorchScript) or rsl-rl checkpoint.
        env: the env it will act in (a checkpoint needs it to build the runner).
        agent: rsl-rl runner config for a checkpoint (default: ``agent.yaml`` next to it, else the
            env's task ``agent`` section).
        flag: the command-line flag that named ``path``, first word of every error.
        same_task: refuse a checkpoint trained on a task of another name (``play``); an evaluation
            scenario builds its own task, so by default only the observation and action sizes must fit.

    Raises:
        FileNotFoundError: no such file. UserError: unreadable, or it does not fit the env.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"policy {path} not found (an exported actor .pt2 or .pt, or a model_<it>.pt "
                                "checkpoint)")
    groups = list(_actor_groups(env, agent))
    if file_kind(path) in ("program", "torchscript"):
        actor = load_module(path, device=env.device)
        width = sum(int(env.get_observations()[g].shape[-1]) for g in groups)
        expected = input_size(actor)
        if expected is not None and expected != width:
            raise UserError(f"{flag} {path}: the actor takes {expected} observation inputs, the env of task "
                            f"{_task_name(env)} gives {width} (groups {groups}); use a policy trained on this "
                            "observation layout")

        def exported(obs: TensorDict) -> torch.Tensor:
            return actor(torch.cat([obs[g] for g in groups], dim=-1))

        return _checked(exported, env, path, flag)
    from dls_quadruped.learning.runner import (
        AtomicOnPolicyRunner,
        CheckpointMismatch,
        read_checkpoint,
        runner_config,
    )

    try:
        ckpt = read_checkpoint(path)
    except ValueError as err:
        raise UserError(f"{flag} {path}: unreadable, neither an exported actor nor an rsl-rl checkpoint "
                        f"({err})") from None
    if agent is None:
        run_agent = path.parent / "agent.yaml"
        agent = yaml.safe_load(run_agent.read_text()) if run_agent.is_file() else env.cfg["agent"]
    runner = AtomicOnPolicyRunner(env, runner_config(agent), log_dir=None, device=str(env.device))
    try:
        runner.load_checkpoint(ckpt, str(path), env_state=False, check_task=same_task)
    except CheckpointMismatch as err:
        raise UserError(f"{flag} {err}") from None
    return _checked(runner.get_inference_policy(device=str(env.device)), env, path, flag)


def _checked(policy: Policy, env, path: Path, flag: str) -> Policy:
    """``policy`` after one call on the env's observation: (num_envs, num_actions) finite-shaped
    output, or a ``UserError``."""
    try:
        with torch.inference_mode():
            out = policy(env.get_observations())
    except RuntimeError as err:  # a size mismatch inside the network
        first = " ".join(str(err).strip().splitlines()[:2])
        raise UserError(f"{flag} {path}: does not fit the observations of task {_task_name(env)} ({first})") from None
    want = (env.num_envs, env.num_actions)
    if tuple(out.shape) != want:
        raise UserError(f"{flag} {path}: outputs {tuple(out.shape[1:])} actions per robot, the env takes "
                        f"{env.num_actions} (the latent action)")
    return policy


def _task_name(env) -> str:
    task = getattr(env, "task", None)
    return getattr(task, "name", "?")


def _actor_groups(env, agent: dict | None) -> list[str]:
    """Observation groups the actor reads (``agent.obs_groups.actor``, default ``["policy"]``)."""
    agent = agent if agent is not None else env.cfg.get("agent", {})
    return list((agent.get("obs_groups") or {}).get("actor", ["policy"]))
