"""The four controllers of thesis 7.3.1, each its own class registered by name, acting in a ``LocomotionEnv``.

Every one implements the controller protocol (``envs/controller.py``) through the configured base
``closed_loop.controller_base.Controller`` and is run by the one loop, ``envs/recorder.record``
(``closed_loop/loop.py``):

=====================  ============================================  =======================================
name                   class                                         command, rate
=====================  ============================================  =======================================
``rl_warm_start``      ``mpc_controllers.RLWarmStartMPC``            MPC action, 100 Hz (2 per env step)
``naive_warm_start``   ``mpc_controllers.NaiveWarmStartMPC``         MPC action, 100 Hz (2 per env step)
``rl_baseline``        :class:`ExpertPolicy`                         the RL expert's action, 50 Hz (``env.step``)
``student``            :class:`StudentPolicy`                        its horizon's first action, 50 Hz
=====================  ============================================  =======================================

Two more cross the RL and naive warm starts (``closed_loop/split_warm_start.py``): ``rl_gait_naive_forces`` and
``naive_gait_rl_forces``, the student's gait and footholds with the naive forces and the other way round.

* ``rl_warm_start``: the distilled student(s) warm-start the sampling MPC (``closed_loop/mpc_controllers.py``);
* ``naive_warm_start``: the model-based baseline (``mpc.baseline``): periodic trot, heuristic footholds (eq.
  2.2.4), MPC warm-started by its previous solution only;
* ``rl_baseline``: the RL expert alone (its action at 50 Hz, held for the 4 physics steps);
* ``student``: the student alone (the decoded first action of its horizon).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from dls_quadruped.closed_loop.controller_base import (
    Controller,
    call,
    check_output,
    load_student,
)
from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.closed_loop.mpc_controllers import (
    MPCController,
    NaiveWarmStartMPC,
    RLWarmStartMPC,
)
from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY
from dls_quadruped.closed_loop.split_warm_start import NaiveGaitStudentForcesMPC, StudentGaitNaiveForcesMPC
from dls_quadruped.control.latent_action import ACTION_DIM

__all__ = ["CONTROLLERS", "Controller", "ControllerConfig", "ExpertPolicy", "MPCController", "NaiveWarmStartMPC",
           "PolicyController", "RLWarmStartMPC", "StudentPolicy", "make_controller"]


class PolicyController(Controller):
    """A network queried once per env step on the observation, its (B, 28) raw action through ``env.step``
    (the env checks it). A subclass sets ``_policy`` (obs -> action) and ``_what`` (its name in errors)."""

    _what = "policy"

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        self._action: torch.Tensor | None = None

    def _policy(self, obs: TensorDict) -> torch.Tensor:
        raise NotImplementedError

    def prepare(self, obs: TensorDict) -> None:
        out = call(self._what, self._policy, obs)
        check_output(self._what, obs["policy"], out, ACTION_DIM)
        self._action = out

    def act(self, obs: TensorDict, substep: int) -> torch.Tensor:
        return self._action


class ExpertPolicy(PolicyController):
    """``rl_baseline``: the RL expert alone (``cfg.policy``)."""

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        from dls_quadruped.eval.policy import load_policy

        self._expert = load_policy(cfg.policy, env)
        self._what = f"policy {cfg.policy}"

    def _policy(self, obs: TensorDict) -> torch.Tensor:
        return self._expert(obs)


class StudentPolicy(PolicyController):
    """``student``: the student alone, the decoded first action of its horizon (``cfg.student``)."""

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        (path,) = cfg.students
        self._student, _ = load_student(path, env, str(env.device))
        self._what = f"student {path}"

    def _policy(self, obs: TensorDict) -> torch.Tensor:
        return self._student.first_action(obs["policy"])


CONTROLLER_REGISTRY.register("rl_warm_start", RLWarmStartMPC, "the distilled student(s) warm-start the sampling MPC")
CONTROLLER_REGISTRY.register("naive_warm_start", NaiveWarmStartMPC,
                             "the model-based baseline: trot, heuristic footholds, MPC warm-started by its last plan")
CONTROLLER_REGISTRY.register("rl_baseline", ExpertPolicy, "the RL expert alone")
CONTROLLER_REGISTRY.register("student", StudentPolicy, "the student alone, the first action of its horizon")
CONTROLLER_REGISTRY.register("rl_gait_naive_forces", StudentGaitNaiveForcesMPC,
                             "the MPC warm-started by the student's gait and footholds and the naive forces")
CONTROLLER_REGISTRY.register("naive_gait_rl_forces", NaiveGaitStudentForcesMPC,
                             "the MPC warm-started by the naive trot and heuristic footholds and the student's forces")
CONTROLLERS = CONTROLLER_REGISTRY.names()
"""Controller names (thesis 7.3.1 plus the student alone), in registration order."""


def make_controller(cfg: ControllerConfig, env) -> Controller:
    """The controller ``cfg.name`` acting in ``env`` (``closed_loop/registry.py``)."""
    return CONTROLLER_REGISTRY.get(cfg.name)(cfg, env)
