"""The controller protocol: what acts in a ``LocomotionEnv``, and the one env step that runs any controller.

A controller maps the env's observation and robot state to a command at its own rate:

* ``physics_steps``: its rate, one command per ``physics_steps`` physics steps (``env.decimation //
  physics_steps`` commands per env step); None: one command per env step through ``env.step`` (a policy);
* ``prepare(obs)``: once per env step, before its commands (a network query on the observation);
* ``act(obs, substep) -> Command``: command ``substep`` of the env step, from the env's state at that moment:
  a raw action (B, A) for the action manager, or world :class:`References` straight to the backend;
* ``reset(env_ids)``: the env restarted these robots' episodes (drop their memory); ``reset_where(env_mask)``:
  the same for a (B,) bool mask, what the episode recorder calls after every step (a controller whose memory is
  on the device overrides it to read nothing back; the default reads the mask and calls ``reset``, and reads
  nothing at all when ``reset`` is not overridden).

:func:`step` is the one env step under a controller (``envs/recorder.record`` calls it every step):

* ``physics_steps`` None and a raw action: ``env.step(action)`` -- the env checks the action (a row that is not
  finite is zeroed and its robot terminated as ``nonfinite_action``), as for any policy;
* otherwise ``env.step_controlled(physics)``, ``physics`` sending the commands one after the other, each held for
  ``physics_steps`` physics steps: a raw action through ``env.apply_action`` (``replan`` after the first, so the
  action terms see the env step's change; ``finite`` when the controller's ``finite_commands`` says its actions
  are finite by construction, so the env does not read them back to check), references through
  ``env.apply_references``.

Implemented by the eval suite's policies (:class:`PolicyController`), the closed loop's controllers
(``closed_loop/controllers.py``: the RL expert, the student, the RL-warm-started and the naive-warm-started MPC;
the naive one also runs the model-based baseline in the home task, ``closed_loop/baseline_run.py``) and the
balance controller (``eval/balance_run.py``).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict


@dataclass(frozen=True)
class References:
    """World-frame references for the backend's low-level controller (``env.apply_references``), B robots.

    Attributes:
        freq: (B, 4) [Hz] step frequency; duty: (B, 4) stance fraction; p_td_w: (B, 4, 3) [m] touch-down
        targets, world frame; F_w: (B, 4, 3) [N] stance forces, world frame.
    """

    freq: torch.Tensor
    duty: torch.Tensor
    p_td_w: torch.Tensor
    F_w: torch.Tensor


Command = torch.Tensor | References
"""A (B, A) raw action (the action manager's input) or world :class:`References`."""


class EnvController(ABC):
    """A controller acting in ``env`` at its own rate (the module docstring).

    Args:
        env: the env it acts in (``LocomotionEnv``; a policy needs only ``step``).
        physics_steps: physics steps each command is held for, dividing ``env.decimation``; None: one command per
            env step, a raw action through ``env.step``.

    Attributes:
        prepare_seconds, act_seconds: [s] spent in :meth:`prepare` and :meth:`act` under :func:`step`.
        finite_commands: its raw actions are finite by construction (the sampling MPC's), so ``env.apply_action``
            does not check them (a host read); False: checked, a non-finite entry raises.

    Raises:
        ValueError: ``physics_steps`` is not a positive int dividing ``env.decimation``.
    """

    name = "controller"
    finite_commands = False

    def __init__(self, env, physics_steps: int | None = None):
        if physics_steps is not None and (isinstance(physics_steps, bool) or not isinstance(physics_steps, int)
                                          or physics_steps < 1 or env.decimation % physics_steps):
            raise ValueError(f"physics_steps must be an int >= 1 dividing the env step's {env.decimation} physics "
                             f"steps (env.decimation), got {physics_steps!r}")
        self.env = env
        self.physics_steps = physics_steps
        self.prepare_seconds = 0.0
        self.act_seconds = 0.0

    @property
    def commands_per_step(self) -> int:
        """Commands per env step: ``env.decimation // physics_steps`` (1 at the policy rate)."""
        return 1 if self.physics_steps is None else self.env.decimation // self.physics_steps

    @property
    def rate_hz(self) -> float:
        """[Hz] commands per second."""
        return self.commands_per_step / self.env.step_dt

    def reset(self, env_ids: torch.Tensor) -> None:
        """The env restarted the episodes of these (n,) robots: forget what the controller kept of them."""

    def reset_where(self, env_mask: torch.Tensor) -> None:
        """:meth:`reset` of the robots of the (B,) bool ``env_mask`` (none may be set). Here: nothing when the
        subclass keeps no memory (``reset`` not overridden), else one host read of the mask and ``reset`` of its
        robots if any; a controller whose memory is on the device overrides this with masked updates."""
        if type(self).reset is EnvController.reset:
            return
        ids = torch.nonzero(env_mask.detach().cpu()).flatten()
        if ids.numel():
            self.reset(ids)

    def prepare(self, obs: TensorDict) -> None:
        """Once per env step, before its commands: what the step's commands need from the observation."""

    @abstractmethod
    def act(self, obs: TensorDict, substep: int) -> Command:
        """Command ``substep`` (0 .. ``commands_per_step`` - 1) of the env step whose observation is ``obs``,
        from the env's state now."""

    def step(self, obs: TensorDict) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One env step under this controller: :func:`step` (a controller does not override it)."""
        return step(self, obs)


def _send(env, command: Command, num_physics_steps: int, replan: bool, finite: bool = False) -> None:
    if isinstance(command, References):
        env.apply_references(command.freq, command.duty, command.p_td_w, command.F_w, num_physics_steps)
    elif isinstance(command, torch.Tensor):
        env.apply_action(command, num_physics_steps, replan=replan, finite=finite)
    else:
        raise TypeError(f"a controller's act must return a raw action tensor or References, got "
                        f"{type(command).__name__}")


def step(controller: EnvController, obs: TensorDict) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
    """One env step of ``controller.env`` under ``controller`` from observation ``obs`` (the module docstring);
    returns the env's ``(obs, reward, dones, extras)``."""
    env = controller.env
    tic = time.perf_counter()
    controller.prepare(obs)
    controller.prepare_seconds += time.perf_counter() - tic

    def act(substep: int) -> Command:
        tic = time.perf_counter()
        command = controller.act(obs, substep)
        controller.act_seconds += time.perf_counter() - tic
        return command

    if controller.physics_steps is None:
        command = act(0)
        if isinstance(command, torch.Tensor):
            return env.step(command)
        return env.step_controlled(lambda: _send(env, command, env.decimation, replan=False))

    def physics() -> None:
        for j in range(controller.commands_per_step):
            _send(env, act(j), controller.physics_steps, replan=j > 0, finite=controller.finite_commands)

    return env.step_controlled(physics)


class PolicyController(EnvController):
    """A policy as a controller: ``policy(obs) -> (B, A)`` raw actions once per env step (``env.step``).

    Args:
        policy: observation groups -> (B, A) raw actions; name: what it is called in reports.
    """

    def __init__(self, env, policy: Callable[[TensorDict], torch.Tensor], name: str = "policy"):
        super().__init__(env)
        self.policy, self.name = policy, name
        self._action: torch.Tensor | None = None

    def prepare(self, obs: TensorDict) -> None:
        self._action = self.policy(obs)

    def act(self, obs: TensorDict, substep: int) -> torch.Tensor:
        return self._action
