"""Warm starts for the sampling MPC (thesis 3.2, 7.3): naive (shifted previous solution) and external.

Any encoded action (B, D) is a valid warm start; these helpers build the common ones:

* :func:`naive` - previous best sample shifted by one MPC period (see ``encodings.shift_encoded``);
* :func:`from_latent_action` - a single latent action (e.g. the RL policy's, in physical units)
  held over the horizon and encoded, i.e. what a non-horizon policy can offer;
* :func:`from_horizon` - a horizon of latent actions (e.g. a student policy's decoded output);
* :func:`nominal_trot` - the feed-forward default: trot at 1.5 Hz, duty 0.6, feet under the
  hips, weight shared by the stance legs (F_z = m g / 2 for a trot).
"""

from __future__ import annotations

import torch

from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import ACTION_DIM, encode, shift_encoded


def naive(previous_best: torch.Tensor, cfg: SamplerConfig) -> torch.Tensor:
    """Previous solution shifted by mpc_period / dt horizon steps. previous_best: (B, D) -> (B, D)."""
    return shift_encoded(previous_best, cfg.encoding, cfg.mpc_period / cfg.dt)


def from_horizon(actions: torch.Tensor, cfg: SamplerConfig) -> torch.Tensor:
    """Encode a horizon of latent actions (B, N, 28) (physical units, frame H) -> (B, D)."""
    return encode(actions, cfg.encoding)


def from_latent_action(action: torch.Tensor, cfg: SamplerConfig) -> torch.Tensor:
    """Hold one latent action (B, 28) over the horizon and encode it -> (B, D)."""
    if action.dim() != 2 or action.shape[-1] != ACTION_DIM:
        raise ValueError(f"action must have shape (B, {ACTION_DIM}), got {tuple(action.shape)}")
    return encode(action[:, None, :].expand(-1, cfg.horizon, ACTION_DIM), cfg.encoding)


def nominal_trot(batch: int, cfg: SamplerConfig, freq: float = 1.5, duty: float = 0.6,
                 stance_legs: float = 2.0) -> torch.Tensor:
    """Feed-forward trot warm start (B, D): f, d constant, p = 0, F = (0, 0, m g / stance_legs)."""
    action = torch.zeros(batch, ACTION_DIM)
    action[:, 0:4] = freq
    action[:, 4:8] = duty
    action[:, 16 + 2:28:3] = cfg.action.weight / stance_legs
    return from_latent_action(action, cfg)
