"""Shared fixtures for the MPC tests: a standing AlienGo-like SRBD state and references."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.srbd import SRBDState

FEET_W = torch.tensor([[0.24, 0.134, 0.0265], [0.24, -0.134, 0.0265], [-0.24, 0.134, 0.0265],
                       [-0.24, -0.134, 0.0265]])


def standing(batch: int = 2, height: float = 0.33) -> tuple[SRBDState, Refs]:
    """B robots standing at the origin, feet under the hips, commanded 0.5 m/s forward."""
    state = SRBDState(
        com_pos_w=torch.tensor([[0.0, 0.0, height]]).repeat(batch, 1),
        com_vel_w=torch.zeros(batch, 3),
        euler=torch.zeros(batch, 3),
        ang_vel_b=torch.zeros(batch, 3),
        foot_pos_w=FEET_W.expand(batch, 4, 3).clone(),
    )
    refs = Refs(com_height_w=torch.full((batch,), height), lin_vel_w=torch.tensor([[0.5, 0.0]]).repeat(batch, 1),
                yaw_rate=torch.zeros(batch), foothold_w=FEET_W.expand(batch, 4, 3).clone())
    return state, refs


@pytest.fixture
def standing_pair() -> tuple[SRBDState, Refs]:
    return standing(2)
