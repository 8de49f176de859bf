"""The closed loop's configured controller: the controller protocol (``envs/controller.py``) with a
``ControllerConfig``, the record of its MPC solves, and the checks of the networks it loads.

``closed_loop/controllers.py`` (the policies, the registry's entries) and ``closed_loop/mpc_controllers.py`` (the
sampling MPC's controllers) build on :class:`Controller`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.envs.controller import EnvController


@dataclass
class SolveRecord:
    """One batched MPC solve (B robots), on the MPC's device. step_costs, step_input_costs: (B, N); state_terms:
    (B, 9); the rest (B,). best_cost is the full J of the chosen sample; input_cost its foothold-deviation part;
    state_terms its state part by term (``MPCResult.state_terms``, NaN on a solve without ``record_step_costs``)."""

    best_cost: torch.Tensor
    input_cost: torch.Tensor
    initial_cost: torch.Tensor
    step_costs: torch.Tensor
    step_input_costs: torch.Tensor
    state_terms: torch.Tensor
    warm_start_index: torch.Tensor
    fallback: torch.Tensor
    student_fallback: torch.Tensor


class Controller(EnvController):
    """A controller of the env (``envs/controller.py``) built from a ``ControllerConfig``.

    Args:
        cfg: what to run; kept as ``cfg`` with the env's latent-action configuration (``ControllerConfig.for_env``).
        physics_steps: its rate (``EnvController``); None: one raw action per env step, through ``env.step``.

    Attributes:
        step_records: the MPC solves of the last env step (empty without an MPC).
        solve_seconds: [s] in MPC solves (warm starts, kernel, decoding) during :meth:`act`.
    """

    def __init__(self, cfg: ControllerConfig, env, physics_steps: int | None = None):
        super().__init__(env, physics_steps)
        self.cfg = cfg.for_env(env)
        self.step_records: list[SolveRecord] = []
        self.solve_seconds = 0.0

    @property
    def name(self) -> str:
        return self.cfg.name

    def kernel_seconds(self) -> float:
        """[s] in the MPC's cost kernel (0 without an MPC)."""
        return 0.0


def load_student(path: Path, env, device: str = "cpu"):
    """A student export and its metadata, refused unless it was distilled for the env's observation size."""
    from dls_quadruped.learning.student import load_student as load

    module, meta = load(path, device=device)
    if int(meta.get("obs_dim", -1)) != env.obs_dims["policy"]:
        raise ValueError(f"student {path} was distilled for {meta.get('obs_dim')} observations, "
                         f"the env gives {env.obs_dims['policy']}")
    return module, meta


def check_output(module_name: str, obs: torch.Tensor, out: torch.Tensor, dim: int) -> None:
    """Raise ``ValueError`` unless ``out`` is (B, ``dim``) for the (B, D) observation ``obs``."""
    if out.dim() != 2 or tuple(out.shape) != (obs.shape[0], dim):
        raise ValueError(f"{module_name} returned shape {tuple(out.shape)}, expected ({obs.shape[0]}, {dim})")


def call(module_name: str, fn, obs: torch.Tensor) -> torch.Tensor:
    """Call a policy; a size mismatch becomes one ValueError naming the observation size."""
    try:
        return fn(obs)
    except RuntimeError as err:  # an exported program's (or TorchScript's) shape errors
        raise ValueError(f"{module_name} does not accept the env's observation of {obs.shape[1]} values "
                         f"(trained for another observation?): {str(err).splitlines()[-1][:200]}") from None
