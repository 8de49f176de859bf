"""Batched evaluation episodes: one episode per env, every env started together, no restarts counted.

``run_episodes`` steps a ``VecEnv``-like env (``LocomotionEnv``, or a scripted stand-in in tests)
with a deterministic policy for one episode length and records, per step and env, the base
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

from dls_quadruped.core.progress import progress

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
    already belongs to the next episode, so it is not.
    """
    n = env.num_envs
    steps = int(num_steps or env.max_episode_length)
    command = env.command_manager.command.detach().cpu().numpy().copy()
    vel = np.zeros((steps, n, 3), dtype=np.float32)
    valid = np.zeros((steps, n), dtype=bool)
    reward = np.full((steps, n), np.nan, dtype=np.float32)
    alive = torch.ones(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    length = torch.full((n,), steps, dtype=torch.long)
    obs = env.get_observations()
    with torch.inference_mode(), progress(total=steps, desc=f"{n} episodes", unit="step", leave=False) as bar:
        for k in range(steps):
            obs, rew, dones, extras = env.step(policy(obs))
            done = dones.bool().cpu()
            time_out = extras["time_outs"].bool().cpu()
            reward[k] = np.where(alive.numpy(), (rew.cpu() / env.step_dt).numpy(), np.nan)
            ok = alive & ~done
            valid[k] = ok.numpy()
            vel[k] = velocity(env).cpu().numpy()
            ended = alive & done
            fell |= ended & ~time_out
            length[ended] = k + 1
            alive &= ~done
            bar.set_postfix_str(f"{100.0 * float(alive.float().mean()):.0f} % still up", refresh=False)
            bar.update(1)
    return Traces(command=command, velocity=vel, valid=valid, reward=reward, fell=fell.numpy(),
                  length=length.numpy(), step_dt=float(env.step_dt))


Probe = Callable[[object], torch.Tensor]
"""env -> (B, ...) a quantity read after every policy step."""


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
    n = env.num_envs
    steps = int(num_steps or env.max_episode_length)
    command = env.command_manager.command.detach().cpu().numpy().copy()
    rec: dict[str, np.ndarray] = {}
    valid = np.zeros((steps, n), dtype=bool)
    alive = torch.ones(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    length = torch.full((n,), steps, dtype=torch.long)
    obs = env.get_observations()
    with torch.inference_mode(), progress(total=steps, desc=f"{n} episodes", unit="step", leave=False) as bar:
        for k in range(steps):
            obs, _, dones, extras = env.step(policy(obs))
            done = dones.bool().cpu()
            time_out = extras["time_outs"].bool().cpu()
            valid[k] = (alive & ~done).numpy()
            for name, probe in probes.items():
                value = probe(env).detach().cpu().float().numpy()
                if name not in rec:
                    rec[name] = np.zeros((steps, *value.shape), dtype=np.float32)
                rec[name][k] = value
            ended = alive & done
            fell |= ended & ~time_out
            length[ended] = k + 1
            alive &= ~done
            bar.set_postfix_str(f"{100.0 * float(alive.float().mean()):.0f} % still up", refresh=False)
            bar.update(1)
    return Recording(command=command, probes=rec, valid=valid, fell=fell.numpy(), length=length.numpy(),
                     step_dt=float(env.step_dt))
