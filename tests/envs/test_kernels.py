"""Reward kernels against values worked out by hand."""

from __future__ import annotations

import math

import pytest
import torch

from dls_quadruped.envs.mdp import kernels as K


def test_sek_hand_values():
    e = torch.tensor([[0.3, 0.4], [0.0, 0.0]])  # ||e||^2 = 0.25 and 0
    r = K.sek(e, sigma=0.5)  # exp(-0.25 / 0.5) = exp(-0.5)
    assert r.tolist() == pytest.approx([math.exp(-0.5), 1.0])
    assert float(K.sek(torch.tensor([1.0]), sigma=1.0)) == pytest.approx(math.exp(-0.5))


def test_ssek_stiff_across_slack_along():
    v_ref = torch.tensor([[0.5, 0.5]])
    sigma, alpha = 0.25, 0.2
    u = v_ref / v_ref.norm()  # command direction
    n = torch.tensor([[-u[0, 1], u[0, 0]]])  # lateral direction (D.0.2)
    # 0.15 m/s slower along the command: inside the slack -> full reward
    assert float(K.ssek_velocity(v_ref - 0.15 * u, v_ref, sigma, alpha)) == pytest.approx(1.0)
    # 0.15 m/s faster: also inside the (symmetric) plateau
    assert float(K.ssek_velocity(v_ref + 0.15 * u, v_ref, sigma, alpha)) == pytest.approx(1.0)
    # 0.3 m/s slower: h = 0.3 - 0.2 = 0.1 -> exp(-0.01 / 0.125)
    assert float(K.ssek_velocity(v_ref - 0.3 * u, v_ref, sigma, alpha)) == \
        pytest.approx(math.exp(-0.01 / 0.125), rel=1e-5)
    # 0.15 m/s sideways: stiff, same as SEK exp(-0.0225 / 0.125)
    side = float(K.ssek_velocity(v_ref + 0.15 * n, v_ref, sigma, alpha))
    assert side == pytest.approx(math.exp(-0.0225 / 0.125), rel=1e-5)
    assert side == pytest.approx(float(K.sek(0.15 * n, sigma)), rel=1e-6)
    # alpha = 0 reduces to SEK for any error
    v = torch.tensor([[0.1, 0.9]])
    assert float(K.ssek_velocity(v, v_ref, sigma, 0.0)) == pytest.approx(float(K.sek(v - v_ref, sigma)), rel=1e-5)


def test_ssek_zero_command_is_stiff_and_scalar_dead_zone():
    v = torch.tensor([[0.3, 0.4]])
    assert float(K.ssek_velocity(v, torch.zeros(1, 2), 0.5, 0.4)) == pytest.approx(math.exp(-0.25 / 0.5))
    e = torch.tensor([0.01, -0.015, 0.035])
    r = K.ssek_scalar(e, sigma=0.1, alpha=0.015)  # h = 0, 0, 0.02
    assert r.tolist() == pytest.approx([1.0, 1.0, math.exp(-0.0004 / 0.02)], rel=1e-5)


def test_l1_l2():
    e = torch.tensor([[1.0, -2.0], [0.5, 0.0]])
    assert K.l2(e).tolist() == pytest.approx([5.0, 0.25])
    assert K.l1(e).tolist() == pytest.approx([3.0, 0.5])
    assert K.l2(torch.tensor([-3.0])).tolist() == [9.0]


def test_cost_of_transport_hand_value():
    # two joints: tau qdot = 10*2 = 20, alpha tau^2 = 0.3*100 = 30 -> 50 W;
    # second: tau qdot = -5*4 = -20, 0.3*25 = 7.5 -> max(-12.5, 0) = 0 (no regeneration)
    tau = torch.tensor([[10.0, -5.0]])
    qd = torch.tensor([[2.0, 4.0]])
    cot = K.cost_of_transport(tau, qd, torch.tensor([0.5]), weight=200.0, alpha=0.3)
    assert float(cot) == pytest.approx(50.0 / (200.0 * 0.5))
    # standing still: speed floored at min_speed
    cot0 = K.cost_of_transport(tau, qd, torch.tensor([0.0]), weight=200.0, alpha=0.3, min_speed=0.1)
    assert float(cot0) == pytest.approx(50.0 / 20.0)
