"""Batched evaluation episodes: one episode per env, every env started together, no restarts counted.

``run_episodes`` steps a ``VecEnv``-like env (``LocomotionEnv``, or a scripted stand-in in tests)
with a deterministic policy (an ``envs.controller.PolicyController``, run by ``envs/recorder.record``) for one
episode length and records, per step and env, the base
velocity that the tracking rewards see, the reward divided by the policy step (the per-step
"RL Reward" scale of thesis 7.3, when the env's reward is the evaluation reward), and whether the
env was still in its first episode.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from tensordict import TensorDict

from dls_quadruped.envs.controller import PolicyController
from dls_quadruped.envs.recorder import Probe, record

Policy = Callable[[TensorDict], torch.Tensor]
"""Observation groups (B, D) -> raw actions (B, A)."""
VelocityFn = Callable[[object], torch.Tensor]
"""env -> (B, 3) measured (v_x [m/s], v_y [m/s], omega_z [rad/s]) in the base frame."""


def base_velocity(env) -> torch.Tensor:
    """(B, 3) (v_x, v_y) of the base in the base frame [m/s] and its yaw rate [rad/s], as the
    tracking rewards measure them."""
    from dls_quadruped.envs.mdp.observations import base_ang_vel, base_lin_vel

    return torch.cat([base_lin_vel(env)[:, :2], base_ang_vel(env)[:, 2:3]], dim=-1)


@dataclass
class Traces:
    """One episode per env.

    Attributes:
        command: (E, 3) command at the start of each episode (v_x, v_y [m/s], omega_z [rad/s]).
        velocity: (T, E, 3) measured (v_x, v_y, omega_z) after each step, base frame.
        valid: (T, E) the velocity of that step belongs to the first episode (not after its end).
        reward: (T, E) reward of the step / step_dt (per-step scale), NaN after the episode ended.
        fell: (E,) ended by a non-time-out termination.
        length: (E,) policy steps the episode lasted.
        step_dt: [s] policy step.
    """

    command: np.ndarray
    velocity: np.ndarray
    valid: np.ndarray
    reward: np.ndarray
    fell: np.ndarray
    length: np.ndarray
    step_dt: float


def run_episodes(env, policy: Policy, num_steps: int | None = None, velocity: VelocityFn = base_velocity) -> Traces:
    """Run every env of ``env`` for ``num_steps`` policy steps (default: one episode) from its
    current state; data after an env's first termination is masked out (its restart is ignored).

    The env must expose ``num_envs``, ``step_dt``, ``max_episode_length``, ``get_observations()``,
    ``step(actions) -> (obs, reward, dones, extras)`` with ``extras["time_outs"]``, and
    ``command_manager.command``. The reward of a step is computed by the env before a terminated
    env resets, so it is kept on the step that ends the episode; the velocity read after that step
    already belongs to the next episode, so it is not (``envs/recorder.py``).
    """
    rec = record(env, PolicyController(env, policy), {"velocity": velocity}, num_steps)
    return Traces(command=rec.command, velocity=rec.after["velocity"].astype(np.float32, copy=False), valid=rec.valid,
                  reward=rec.masked(rec.reward, rec.active), fell=rec.fell, length=rec.length, step_dt=rec.step_dt)


@dataclass
class Recording:
    """One episode per env, with named per-step probes.

    Attributes:
        command: (E, 3) command of each episode (v_x, v_y [m/s], omega_z [rad/s]).
        probes: name -> (T, E, ...) value read after each step (float32; garbage where not ``valid``).
        valid: (T, E) the step's probes belong to the first episode (before its end).
        fell: (E,) ended by a non-time-out termination.
        length: (E,) policy steps the episode lasted.
        step_dt: [s] policy step.
    """

    command: np.ndarray
    probes: dict[str, np.ndarray]
    valid: np.ndarray
    fell: np.ndarray
    length: np.ndarray
    step_dt: float


def record_episodes(env, policy: Policy, probes: dict[str, Probe], num_steps: int | None = None) -> Recording:
    """Like ``run_episodes``, but reads any set of ``probes`` after every step instead of the
    velocity alone. A probe read after the step that ends an env's episode already sees its next
    episode (the env resets inside ``step``), so that step is not ``valid``."""
    as_float = {name: (lambda env, p=probe: p(env).float()) for name, probe in probes.items()}
    rec = record(env, PolicyController(env, policy), as_float, num_steps)
    return Recording(command=rec.command, probes=rec.after, valid=rec.valid, fell=rec.fell, length=rec.length,
                     step_dt=rec.step_dt)
