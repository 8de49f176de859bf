"""The one recorder of batched episodes: every env plays one episode from its current state, and what follows
an env's first end (its restart inside ``step``) is masked out.

:func:`record` steps a ``VecEnv``-like env (``LocomotionEnv``, or a scripted stand-in in tests) with any step
function -- a policy (``env.step(policy(obs))``), a controller that runs the physics itself
(``env.step_controlled(physics)``) -- and keeps, per step k and env e:

* ``active[k, e]``: step k belongs to e's first episode (the episode was running before the step). What the
  step itself produced -- its reward, a controller's plans, a probe read *before* the step -- belongs to it;
* ``valid[k, e]``: the state after step k still belongs to that episode (active, and the step did not end it).
  The env resets an ended robot inside ``step``, so a probe read *after* the step that ended the episode
  already sees the next one;
* the reward of the step divided by the policy step (``env.step_dt``: the per-step "RL Reward" scale of
  thesis 7.3 when the env's reward is the evaluation reward), computed by the env before it resets;
* named probes ``env -> (E, ...)`` read before or after every step, stored raw in their own dtype (zeros on
  steps not simulated): the masks above say which entries count (:meth:`EpisodeRecord.masked`);
* ``fell[e]``: the episode ended by a termination other than a time-out; ``length[e]``: its steps.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from tensordict import TensorDict

from dls_quadruped.core.progress import progress
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat

Probe = Callable[[object], torch.Tensor]
"""env -> (E, ...) a quantity read before or after every step (the env axis first where it is masked)."""
StepFn = Callable[[TensorDict], tuple[TensorDict, torch.Tensor, torch.Tensor, dict]]
"""obs -> (obs, reward (E,), dones (E,), extras with ``extras["time_outs"]`` (E,)): one env step."""



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
        step_dt: [s] one step; steps: steps simulated (< T when the loop stopped once every episode had ended);
        wall_s: [s] wall-clock time of the loop.
    """

    command: np.ndarray
    active: np.ndarray
    valid: np.ndarray
    reward: np.ndarray
    fell: np.ndarray
    length: np.ndarray
    step_dt: float
    steps: int
    before: dict[str, np.ndarray] = field(default_factory=dict)
    after: dict[str, np.ndarray] = field(default_factory=dict)
    wall_s: float = 0.0

    @staticmethod
    def masked(values: np.ndarray, where: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """``values`` (T, E, ...) where ``where`` (T, E) holds, ``fill`` elsewhere, in the values' dtype."""
        keep = where.reshape(where.shape + (1,) * (values.ndim - where.ndim))
        return np.where(keep, values, fill).astype(values.dtype, copy=False)


def _store(out: dict[str, np.ndarray], name: str, k: int, steps: int, value: torch.Tensor) -> None:
    """``out[name][k] = value`` (on the host), allocating (steps, *value.shape) zeros of its dtype at first."""
    value = value.detach().cpu().numpy()
    if name not in out:
        out[name] = np.zeros((steps, *value.shape), dtype=value.dtype)
    out[name][k] = value


def record(env, step: StepFn, after: dict[str, Probe] | None = None, num_steps: int | None = None, *,
           before: dict[str, Probe] | None = None, stop_when_all_ended: bool = False,
           on_reset: Callable[[torch.Tensor], None] | None = None, desc: str | None = None) -> EpisodeRecord:
    """Run every env of ``env`` for ``num_steps`` steps (default: ``env.max_episode_length``) from its current
    state under ``step``, reading the probes ``before`` and ``after`` every step, in ``torch.inference_mode``.

    Args:
        env: exposes ``num_envs``, ``step_dt``, ``max_episode_length``, ``get_observations()`` and
            ``command_manager.command`` (E, 3).
        stop_when_all_ended: stop once every env's first episode has ended: the rest would be masked anyway.
        on_reset: called with the (n,) ids of the envs that ended at a step (the env restarted them), e.g. for a
            controller to drop their memory; not after the step that ends the last episode when the loop stops.
        desc: the progress bar's label (default "E episodes").
    """
    n = env.num_envs
    steps = int(num_steps or env.max_episode_length)
    command = env.command_manager.command.detach().cpu().numpy().copy()
    active = np.zeros((steps, n), dtype=bool)
    valid = np.zeros((steps, n), dtype=bool)
    reward = np.zeros((steps, n), dtype=np.float32)
    read_before: dict[str, np.ndarray] = {}
    read_after: dict[str, np.ndarray] = {}
    alive = torch.ones(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    length = torch.full((n,), steps, dtype=torch.long)
    simulated = 0
    obs = env.get_observations()
    wall0 = time.perf_counter()
    with torch.inference_mode(), progress(total=steps, desc=desc or f"{n} episodes", unit="step", leave=False) as bar:
        for k in range(steps):
            active[k] = alive.numpy()
            for name, probe in (before or {}).items():
                _store(read_before, name, k, steps, probe(env))
            obs, rew, dones, extras = step(obs)
            done = dones.detach().cpu().bool()
            time_out = extras["time_outs"].detach().cpu().bool()
            reward[k] = (rew.detach().cpu() / env.step_dt).numpy()
            valid[k] = (alive & ~done).numpy()
            for name, probe in (after or {}).items():
                _store(read_after, name, k, steps, probe(env))
            ended = alive & done
            fell |= ended & ~time_out
            length[ended] = k + 1
            alive &= ~done
            simulated = k + 1
            bar.set_postfix_str(f"{100.0 * float(alive.float().mean()):.0f} % still up", refresh=False)
            bar.update(1)
            if stop_when_all_ended and not bool(alive.any()):
                break
            if on_reset is not None and bool(done.any()):
                on_reset(torch.nonzero(done).flatten())
    return EpisodeRecord(command=command, active=active, valid=valid, reward=reward, fell=fell.numpy(),
                         length=length.numpy(), step_dt=float(env.step_dt), steps=simulated, before=read_before,
                         after=read_after, wall_s=time.perf_counter() - wall0)
