"""Termination terms: (B,) bool. Terms flagged ``time_out: true`` in the task are reported to rsl-rl as
``time_outs`` (bootstrapped, not failures)."""

from __future__ import annotations

import math

import torch

from dls_quadruped.envs.mdp.observations import projected_gravity


def time_out(env) -> torch.Tensor:
    """The episode reached its length (15 s = 750 policy steps by default)."""
    return env.episode_length_buf >= env.max_episode_length


def base_contact(env) -> torch.Tensor:
    """The trunk, a hip or a thigh touches the ground (from the backend's contact check)."""
    return env.state.base_contact.bool()


def bad_orientation(env, limit_deg: float = 45.0) -> torch.Tensor:
    """The base tilts more than ``limit_deg`` from upright: angle between base z and world z."""
    cos_tilt = -projected_gravity(env)[:, 2]
    return cos_tilt < math.cos(math.radians(limit_deg))


def sim_diverged(env) -> torch.Tensor:
    """The simulation of this robot became invalid (NaN or MuJoCo warning): reset it."""
    return env.state.diverged.bool()
