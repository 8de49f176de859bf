"""Velocity-command samplers: ``sampler(env, env_ids, **params) -> (n, 3)`` (v_x, v_y [m/s], omega_z [rad/s]).

The command manager calls the sampler for the envs whose resampling timer expired or that reset.
Ranges are ``[low, high]`` and may be changed at run time by a curriculum (e.g. speed growth).
"""

from __future__ import annotations

import torch


def _uniform(n: int, rng: tuple[float, float], device) -> torch.Tensor:
    return torch.empty(n, device=device).uniform_(float(rng[0]), float(rng[1]))


def uniform_velocity(env, env_ids: torch.Tensor, lin_vel_x: tuple[float, float], lin_vel_y: tuple[float, float],
                     ang_vel_z: tuple[float, float], standing_fraction: float = 0.0) -> torch.Tensor:
    """Independent uniform components (omnidirectional, or forward when lin_vel_x >= 0); a
    ``standing_fraction`` of the samples is set to zero (learn to stand)."""
    n, dev = len(env_ids), env.device
    cmd = torch.stack([_uniform(n, lin_vel_x, dev), _uniform(n, lin_vel_y, dev), _uniform(n, ang_vel_z, dev)], dim=-1)
    stand = torch.rand(n, device=dev) < standing_fraction
    return torch.where(stand[:, None], torch.zeros_like(cmd), cmd)


def omnidirectional_velocity(env, env_ids: torch.Tensor, max_speed: float, ang_vel_z: tuple[float, float],
                             standing_fraction: float = 0.0) -> torch.Tensor:
    """Planar velocity uniform in direction and in speed in [0, max_speed] (a disc, so no corner
    exceeds the task's speed, e.g. +-1 m/s for base), yaw rate uniform."""
    n, dev = len(env_ids), env.device
    heading = _uniform(n, (-torch.pi, torch.pi), dev)
    speed = _uniform(n, (0.0, max_speed), dev)
    cmd = torch.stack([speed * torch.cos(heading), speed * torch.sin(heading), _uniform(n, ang_vel_z, dev)], dim=-1)
    stand = torch.rand(n, device=dev) < standing_fraction
    return torch.where(stand[:, None], torch.zeros_like(cmd), cmd)


def fixed_velocity(env, env_ids: torch.Tensor, values: list[list[float]]) -> torch.Tensor:
    """Preset commands for evaluation: env i always gets row i of ``values`` ((num_envs, 3): v_x, v_y
    [m/s], omega_z [rad/s]); with a resampling time beyond the episode, one command per episode."""
    table = torch.as_tensor(values, dtype=torch.float32, device=env.device)
    if table.shape != (env.num_envs, 3):
        raise ValueError(f"fixed_velocity: values must be (num_envs, 3) = ({env.num_envs}, 3), got {tuple(table.shape)}")
    return table[env_ids]
