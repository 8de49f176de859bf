"""MPC cost: weights of Tables 9/10 on hand-made deviations, NaN -> +inf."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc.config import CostWeights
from dls_quadruped.mpc.cost import (
    initial_cost,
    input_cost,
    nan_to_inf,
    rollout_cost_reference,
    state_cost,
)
from dls_quadruped.mpc.srbd import robot_srbd_model


def test_state_cost_by_hand(standing):
    w = CostWeights()
    state, refs = standing(1)
    x = state.as_vector().clone()
    x[0, 2] += 0.01  # 1 cm too high: 111500 * 1e-4
    x[0, 3] = 0.0  # 0.5 m/s slower than the command: 5000 * 0.25
    x[0, 6] = 0.1  # roll 0.1 rad: 11200 * 0.01
    x[0, 8] = 1.0  # yaw: weight 0
    x[0, 11] = 0.2  # yaw rate vs 0: 200 * 0.04
    x[0, 0] = 5.0  # x position: weight 0
    expected = 111500 * 1e-4 + 5000 * 0.25 + 11200 * 0.01 + 200 * 0.04
    assert state_cost(x, refs.state_vector(), w).item() == pytest.approx(expected, rel=1e-5)
    assert initial_cost(x, refs, w).item() == pytest.approx(expected, rel=1e-5)


def test_input_cost_only_foothold_xy(standing):
    w = CostWeights()
    _, refs = standing(1)
    u = refs.input_vector().clone()
    u[0, 0] += 0.1  # FL x off by 10 cm: 1000 * 0.01
    u[0, 2] += 1.0  # z: weight 0
    u[0, 12:] = 100.0  # forces: weight 0
    assert input_cost(u, refs.input_vector(), w).item() == pytest.approx(10.0, rel=1e-6)


def test_nan_cost_is_inf_and_rollout_cost_sums_steps(standing):
    assert torch.equal(nan_to_inf(torch.tensor([1.0, float("nan")])), torch.tensor([1.0, float("inf")]))
    state, refs = standing(1)
    model = robot_srbd_model()
    n = 3
    contact = torch.zeros(1, 2, n, 4, dtype=torch.bool)  # free fall, feet jump to the reference footholds
    target = refs.foothold_w[:, None, None].expand(1, 2, n, 4, 3).clone()
    force = torch.zeros(1, 2, n, 4, 3)
    force[0, 1, 0, 0, 0] = float("nan")  # ignored in swing ... but NaN * 0 = NaN must still be caught
    cost = rollout_cost_reference(state.as_vector(), contact, target, force, refs, model, CostWeights(), 0.02)
    # free fall by hand: z_k - z_ref = -g dt^2 k (k-1)/2 (explicit Euler), v_z,k = -k g dt, v_x error -0.5
    g, dt = model.gravity, 0.02
    expected = sum(111500 * (g * dt**2 * k * (k - 1) / 2) ** 2 + 200 * (k * g * dt) ** 2 + 5000 * 0.25
                   for k in range(1, n + 1))
    assert cost[0, 0].item() == pytest.approx(expected, rel=1e-5)
    assert cost[0, 1].item() == float("inf")
