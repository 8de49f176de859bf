"""Velocity-command samplers: ``sampler(env, env_ids, **params) -> (n, 3)`` (v_x, v_y [m/s], omega_z [rad/s]).

The command manager calls the sampler for the envs whose resampling timer expired or that reset.
Ranges are ``[low, high]`` and may be changed at run time by a curriculum (e.g. speed growth).
Every draw comes from the env's episode schedule (stream ``"command"``, ``envs/schedule.py``), so an
episode's commands do not depend on what the other robots did.
"""

from __future__ import annotations

import torch

from dls_quadruped.core.torch_cache import constant_tensor


def _uniform(env, env_ids: torch.Tensor, rng: tuple[float, float] | torch.Tensor, width: int = 1) -> torch.Tensor:
    """(n, width) U[rng) from the env's episode schedule (one draw of stream "command" per env); ``rng`` two numbers
    or the command manager's (2,) float64 device tensor of a range a curriculum may widen."""
    if isinstance(rng, torch.Tensor):
        return env.schedule.uniform(env_ids, (width,), rng[0], rng[1], stream="command")
    return env.schedule.uniform(env_ids, (width,), float(rng[0]), float(rng[1]), stream="command")


def uniform_velocity(env, env_ids: torch.Tensor, lin_vel_x: tuple[float, float], lin_vel_y: tuple[float, float],
                     ang_vel_z: tuple[float, float], standing_fraction: float = 0.0) -> torch.Tensor:
    """Independent uniform components (omnidirectional, or forward when lin_vel_x >= 0); a
    ``standing_fraction`` of the samples is set to zero (learn to stand)."""
    cmd = torch.cat([_uniform(env, env_ids, lin_vel_x), _uniform(env, env_ids, lin_vel_y),
                     _uniform(env, env_ids, ang_vel_z)], dim=-1)
    stand = _uniform(env, env_ids, (0.0, 1.0))[:, 0] < standing_fraction
    return torch.where(stand[:, None], torch.zeros_like(cmd), cmd)


def omnidirectional_velocity(env, env_ids: torch.Tensor, max_speed: float, ang_vel_z: tuple[float, float],
                             standing_fraction: float = 0.0) -> torch.Tensor:
    """Planar velocity uniform in direction and in speed in [0, max_speed] (a disc, so no corner
    exceeds the task's speed, e.g. +-1 m/s for base), yaw rate uniform."""
    heading = _uniform(env, env_ids, (-torch.pi, torch.pi))
    speed = _uniform(env, env_ids, (0.0, max_speed))
    cmd = torch.cat([speed * torch.cos(heading), speed * torch.sin(heading), _uniform(env, env_ids, ang_vel_z)], dim=-1)
    stand = _uniform(env, env_ids, (0.0, 1.0))[:, 0] < standing_fraction
    return torch.where(stand[:, None], torch.zeros_like(cmd), cmd)


def fixed_velocity(env, env_ids: torch.Tensor, values: list[list[float]]) -> torch.Tensor:
    """Preset commands for evaluation: env i always gets row i of ``values`` ((num_envs, 3): v_x, v_y
    [m/s], omega_z [rad/s]); with a resampling time beyond the episode, one command per episode."""
    rows = tuple(tuple(float(v) for v in row) for row in values)
    table = constant_tensor(rows, torch.float32, env.device)  # built once, not at every resampling
    if table.shape != (env.num_envs, 3):
        raise ValueError(f"fixed_velocity: values must be (num_envs, 3) = ({env.num_envs}, 3), "
                         f"got {tuple(table.shape)}")
    return table[env_ids]
