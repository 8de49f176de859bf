"""The one recorder of batched episodes: every env plays one episode from its current state, and what follows
an env's first end (its restart inside ``step``) is masked out.

:func:`record` is the one loop that runs a controller of the controller protocol (``envs/controller.py``: a
policy through ``env.step``, or a controller that runs the physics itself through ``env.step_controlled``) in a
``VecEnv``-like env (``LocomotionEnv``, or a scripted stand-in in tests), one ``envs.controller.step`` per env
step, and keeps, per step k and env e:

* ``active[k, e]``: step k belongs to e's first episode (the episode was running before the step). What the
  step itself produced -- its reward, a controller's plans, a probe read *before* the step -- belongs to it;
* ``valid[k, e]``: the state after step k still belongs to that episode (active, and the step did not end it).
  The env resets an ended robot inside ``step``, so a probe read *after* the step that ended the episode
  already sees the next one;
* the reward of the step divided by the policy step (``env.step_dt``: the per-step "RL Reward" scale of
  thesis 7.3 when the env's reward is the evaluation reward), computed by the env before it resets;
* named probes ``env -> (E, ...)`` read before or after every step, stored raw in their own dtype (zeros on
  steps not simulated): the masks above say which entries count (:meth:`EpisodeRecord.masked`);
* ``fell[e]``: the episode ended by a termination other than a time-out; ``length[e]``: its steps;
  ``episode_return[e]``: the env's raw reward summed in float64 over the episode's steps (the ending one too).

All of it is kept in (T, E, ...) buffers where the values are (the env's device) and read back once, when the
loop ends: a step reads nothing back to the host but, every ``sync_every``-th step, whether every episode has
ended, and the ended robots' ids when ``on_reset`` is given. A policy's captured inputs and actions go to the host
every step (a data set can outgrow the device).

Given a ``policy`` function instead of a controller, the loop applies ``env.step(policy(obs[obs_group]))`` and can
keep the policy's input and action of some envs every step (``capture``): what distillation records of the
expert. ``until`` ends the loop once a step's action is chosen and before it is applied (the data collection
of distillation stops there, its last observation taken but not stepped from). This one loop serves
evaluation, the closed loop, the model-based baseline, balance, the distillation metrics and test set, and the
distillation data collection (``docs/architecture.md``, "The episode loop").
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from dls_quadruped.core.progress import progress
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.envs.controller import EnvController
from dls_quadruped.envs.controller import step as controller_step

Probe = Callable[[object], torch.Tensor]
"""env -> (E, ...) a quantity read before or after every step (the env axis first where it is masked)."""
PolicyFn = Callable[[torch.Tensor], torch.Tensor]
"""(E, obs_dim) observations (or the whole observation TensorDict) -> (E, act_dim) actions for ``env.step``."""


def _rpy(env) -> torch.Tensor:
    return rpy_from_rotmat(quat_to_rotmat(env.state.base_quat_w.double()))


BASE_PROBES: dict[str, Callable] = {
    "base_vel_w": lambda env: env.state.base_lin_vel_w,
    "base_height": lambda env: env.state.base_pos_w[:, 2],
    "roll": lambda env: _rpy(env)[:, 0],
    "pitch": lambda env: _rpy(env)[:, 1],
}
"""Probes of the base every controller run records: (B, 3) world velocity [m/s], (B,) height [m], roll and pitch
[rad] (float64, from the quaternion)."""


@dataclass
class EpisodeRecord:
    """One episode per env: E envs, T steps asked for.

    Attributes:
        command: (E, 3) command at the start (v_x, v_y [m/s], omega_z [rad/s]).
        active: (T, E) bool, step k belongs to the env's first episode (see the module docstring).
        valid: (T, E) bool, the state after step k still belongs to it.
        reward: (T, E) reward of the step / step_dt, raw (mask it with ``active``).
        before, after: probe name -> (T, ...) values read before / after each step, raw.
        fell: (E,) bool, ended by a non-time-out termination; length: (E,) steps the episode lasted (T if it
            did not end).
        episode_return: (E,) float64, the env's reward (not divided by step_dt) summed over the episode's steps
            in step order, the step that ended it included.
        obs, actions: (T, C, obs_dim) policy inputs and (T, C, act_dim) actions of the C captured envs at each
            step, raw, in the policy's dtypes (mask them with ``active[:, capture]``); None without ``capture``.
        step_dt: [s] one step; steps: steps simulated (< T when the loop stopped early: every episode had
            ended, or ``until``); wall_s: [s] wall-clock time of the loop.
    """

    command: np.ndarray
    active: np.ndarray
    valid: np.ndarray
    reward: np.ndarray
    fell: np.ndarray
    length: np.ndarray
    episode_return: np.ndarray
    step_dt: float
    steps: int
    before: dict[str, np.ndarray] = field(default_factory=dict)
    after: dict[str, np.ndarray] = field(default_factory=dict)
    obs: np.ndarray | None = None
    actions: np.ndarray | None = None
    wall_s: float = 0.0

    @staticmethod
    def masked(values: np.ndarray, where: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """``values`` (T, E, ...) where ``where`` (T, E) holds, ``fill`` elsewhere, in the values' dtype."""
        keep = where.reshape(where.shape + (1,) * (values.ndim - where.ndim))
        return np.where(keep, values, fill).astype(values.dtype, copy=False)


def _store(out: dict[str, torch.Tensor], name: str, k: int, steps: int, value: torch.Tensor) -> None:
    """``out[name][k] = value`` where the value is (its device), allocating (steps, *value.shape) zeros of its dtype
    there at first: no host read per step; :func:`_host` reads the buffers back once."""
    value = value.detach()
    if name not in out:
        out[name] = torch.zeros((steps, *value.shape), dtype=value.dtype, device=value.device)
    out[name][k].copy_(value)


def _host(out: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """The buffers of :func:`_store` on the host (one read each)."""
    return {name: buf.cpu().numpy() for name, buf in out.items()}


def record(env, controller: EnvController | None = None, after: dict[str, Probe] | None = None,
           num_steps: int | None = None, *, before: dict[str, Probe] | None = None, stop_when_all_ended: bool = False,
           on_reset: Callable[[torch.Tensor], None] | None = None, desc: str | None = None,
           policy: PolicyFn | None = None, obs_group: str | None = None, capture: bool | slice = False,
           until: Callable[[], bool] | None = None, no_grad: bool = False, sync_every: int = 1) -> EpisodeRecord:
    """Run every env of ``env`` for ``num_steps`` steps (default: ``env.max_episode_length``) from its current
    state under ``controller`` (acting in ``env``; or ``policy``), reading the probes ``before`` and ``after``
    every step, in ``torch.inference_mode`` (``torch.no_grad`` with ``no_grad``).

    Args:
        env: exposes ``num_envs``, ``step_dt``, ``max_episode_length``, ``get_observations()`` and
            ``command_manager.command`` (E, 3); with ``policy``, ``step(actions)`` too.
        controller: a controller of ``env`` (``envs/controller.py``), one ``envs.controller.step`` per step and
            its ``reset_where(done)`` after every step (masked: the robots that ended restart); exactly one of
            ``controller`` and ``policy``.
        stop_when_all_ended: stop once every env's first episode has ended: the rest would be masked anyway (seen
            at the ``sync_every``-th steps).
        on_reset: called, after ``controller.reset_where``, with the (n,) ids (on the host) of the envs that ended
            at a step (the env restarted them): a host read every step; neither is called after the step that ends
            the last episode when the loop stops.
        desc: the progress bar's label (default "E episodes").
        policy: (E, obs_dim) ``obs[obs_group]`` (the TensorDict without ``obs_group``) -> (E, act_dim) actions,
            applied with ``env.step``.
        capture: with ``policy`` and ``obs_group``: keep the policy input and action of every env (True) or of the
            envs ``capture`` (a slice of the env axis) each step, in ``EpisodeRecord.obs`` / ``actions``.
        until: asked once a step's action is chosen (after ``policy`` or the ``before`` probes), before it is
            applied: True ends the loop without that step (it is not ``active``).
        no_grad: ``torch.no_grad`` instead of ``torch.inference_mode``: for an env that goes on being used with
            autograd afterwards (an in-process simulator would keep inference tensors created at a reset,
            which later in-place updates refuse).
        sync_every: read back whether every episode has ended (``stop_when_all_ended``, the progress bar) every
            ``sync_every``-th step and at the last: 1 stops at the step where the last episode ended; more lets a
            device loop run that many steps without a host read (the loop may then stop up to ``sync_every`` - 1
            steps later, steps whose entries are masked anyway).

    Raises:
        ValueError: neither or both of ``controller`` and ``policy``; a controller of another env; ``capture``
            without a policy and an ``obs_group``; ``sync_every`` not an int >= 1.
    """
    if (controller is None) == (policy is None):
        raise ValueError("record needs exactly one of controller (envs/controller.py) and policy (obs -> actions)")
    if controller is not None and controller.env is not env:
        raise ValueError("record: the controller acts in another env than the one recorded")
    if capture is not False and (policy is None or obs_group is None):
        raise ValueError("capture keeps a policy's observations and actions: give policy and obs_group with it")
    n = env.num_envs
    steps = int(num_steps or env.max_episode_length)
    if not isinstance(sync_every, int) or isinstance(sync_every, bool) or sync_every < 1:
        raise ValueError(f"record: sync_every must be an int >= 1 (steps between reads of the episodes' ends), "
                         f"got {sync_every!r}")
    command = env.command_manager.command.detach().cpu().numpy().copy()
    read_before: dict[str, torch.Tensor] = {}
    read_after: dict[str, torch.Tensor] = {}
    captured: dict[str, torch.Tensor] = {}
    books: dict[str, torch.Tensor] = {}  # (T, E) active, valid and reward, on the env's device
    alive = fell = length = episode_return = None  # (E,) on the env's device, made at the first step
    kept = slice(None) if capture is True else (capture or None)
    simulated = 0
    obs = env.get_observations()
    wall0 = time.perf_counter()
    grad_mode = torch.no_grad() if no_grad else torch.inference_mode()
    with grad_mode, progress(total=steps, desc=desc or f"{n} episodes", unit="step", leave=False) as bar:
        for k in range(steps):
            for name, probe in (before or {}).items():
                _store(read_before, name, k, steps, probe(env))
            if policy is not None:
                obs_in = obs if obs_group is None else obs[obs_group]
                action = policy(obs_in)
                if kept is not None:  # on the host: a data set can outgrow the device
                    _store(captured, "obs", k, steps, obs_in[kept].cpu())
                    _store(captured, "actions", k, steps, action[kept].cpu())
            if until is not None and until():
                break
            obs, rew, dones, extras = env.step(action) if policy is not None else controller_step(controller, obs)
            done = dones.detach().bool()
            time_out = extras["time_outs"].detach().bool()
            rew = rew.detach()
            if alive is None:
                alive = torch.ones(n, dtype=torch.bool, device=done.device)
                fell = torch.zeros(n, dtype=torch.bool, device=done.device)
                length = torch.full((n,), steps, dtype=torch.long, device=done.device)
                episode_return = torch.zeros(n, dtype=torch.float64, device=done.device)
            _store(books, "active", k, steps, alive)
            _store(books, "reward", k, steps, (rew / env.step_dt).float())
            episode_return += torch.where(alive, rew.double(), 0.0)  # the ending step's reward counts
            _store(books, "valid", k, steps, alive & ~done)
            for name, probe in (after or {}).items():
                _store(read_after, name, k, steps, probe(env))
            ended = alive & done
            fell |= ended & ~time_out
            length = torch.where(ended, k + 1, length)
            alive &= ~done
            simulated = k + 1
            bar.update(1)
            if (k + 1) % sync_every == 0 or k + 1 == steps:  # the one host read of the loop's own books
                up = alive.float().mean().item()
                bar.set_postfix_str(f"{100.0 * up:.0f} % still up", refresh=False)
                if stop_when_all_ended and up == 0.0:
                    break
            if controller is not None:
                controller.reset_where(done)  # masked: no host read (``EnvController.reset_where``)
            if on_reset is not None and bool(done.any()):
                on_reset(torch.nonzero(done.cpu()).flatten())
    host = _host(books)
    blank = {"active": np.zeros((steps, n), dtype=bool), "valid": np.zeros((steps, n), dtype=bool),
             "reward": np.zeros((steps, n), dtype=np.float32)}
    host = {key: host.get(key, blank[key]) for key in blank}  # nothing simulated: no step stored
    if alive is None:
        fell, length = torch.zeros(n, dtype=torch.bool), torch.full((n,), steps, dtype=torch.long)
        episode_return = torch.zeros(n, dtype=torch.float64)
    captured = _host(captured)
    return EpisodeRecord(command=command, active=host["active"], valid=host["valid"], reward=host["reward"],
                         fell=fell.cpu().numpy(), length=length.cpu().numpy(),
                         episode_return=episode_return.cpu().numpy(), step_dt=float(env.step_dt), steps=simulated,
                         before=_host(read_before), after=_host(read_after), obs=captured.get("obs"),
                         actions=captured.get("actions"), wall_s=time.perf_counter() - wall0)
