"""Load a policy to evaluate: an exported actor (TorchScript) or an rsl-rl checkpoint.

* exported actor (``exported/policy.pt``, ``docs/policies/base_actor.pt``): TorchScript module with
  its observation normaliser, input the actor's observation group(s) concatenated, output the raw
  action mean;
* checkpoint (``runs/<task>/<run>/model_<it>.pt``): rebuilt through rsl-rl's runner with the run's
  ``agent.yaml`` (next to the checkpoint) or else the task's ``agent`` section, deterministic
  inference policy.
"""

from __future__ import annotations

from pathlib import Path

import torch
import yaml
from tensordict import TensorDict

from dls_quadruped.eval.rollout import Policy


def _is_torchscript(path: Path) -> bool:
    try:
        torch.jit.load(str(path), map_location="cpu")
    except RuntimeError:  # not a TorchScript archive (a pickled checkpoint dict)
        return False
    return True


def load_policy(path: str | Path, env, agent: dict | None = None) -> Policy:
    """A deterministic policy ``obs TensorDict -> (B, A) actions`` for ``env``.

    Args:
        path: exported TorchScript actor or rsl-rl checkpoint.
        env: the env it will act in (a checkpoint needs it to build the runner).
        agent: rsl-rl runner config for a checkpoint (default: ``agent.yaml`` next to it, else the
            env's task ``agent`` section).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"policy {path} not found (an exported actor .pt or a model_<it>.pt checkpoint)")
    if _is_torchscript(path):
        actor = torch.jit.load(str(path), map_location=env.device).eval()
        groups = list(_actor_groups(env, agent))

        def exported(obs: TensorDict) -> torch.Tensor:
            return actor(torch.cat([obs[g] for g in groups], dim=-1))

        return exported
    from dls_quadruped.learning.runner import AtomicOnPolicyRunner, runner_config

    if agent is None:
        run_agent = path.parent / "agent.yaml"
        agent = yaml.safe_load(run_agent.read_text()) if run_agent.is_file() else env.cfg["agent"]
    runner = AtomicOnPolicyRunner(env, runner_config(agent), log_dir=None, device=str(env.device))
    runner.load(str(path))
    return runner.get_inference_policy(device=str(env.device))


def _actor_groups(env, agent: dict | None) -> list[str]:
    """Observation groups the actor reads (``agent.obs_groups.actor``, default ``["policy"]``)."""
    agent = agent if agent is not None else env.cfg.get("agent", {})
    return list((agent.get("obs_groups") or {}).get("actor", ["policy"]))
