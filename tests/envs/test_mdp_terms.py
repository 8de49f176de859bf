"""Observation, reward and termination terms on hand-made states (values worked out by hand)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from dls_quadruped.envs.mdp import observations as O
from dls_quadruped.envs.mdp import rewards as R
from dls_quadruped.envs.mdp import terminations as T
from dls_quadruped.robots.aliengo import constants as C


def quat_axis_angle(axis, angle):
    a = torch.tensor(axis, dtype=torch.float32)
    a = a / a.norm()
    return torch.cat([torch.tensor([math.cos(angle / 2)]), a * math.sin(angle / 2)])


def fake_env(quats, lin_vel_w=None, ang_vel_b=None, foot_z=None, contact_force=None, command=None):
    b = len(quats)
    state = SimpleNamespace(
        base_pos_w=torch.tensor([[0.0, 0.0, 0.40]]).repeat(b, 1),
        base_quat_w=torch.stack(quats),
        base_lin_vel_w=torch.zeros(b, 3) if lin_vel_w is None else lin_vel_w,
        base_ang_vel_b=torch.zeros(b, 3) if ang_vel_b is None else ang_vel_b,
        joint_pos=torch.as_tensor(C.NOMINAL_JOINT_POS, dtype=torch.float32).repeat(b, 1),
        foot_pos_w=torch.zeros(b, 4, 3),
        foot_force_w=torch.zeros(b, 4, 3),
    )
    if foot_z is not None:
        state.foot_pos_w[..., 2] = foot_z
    if contact_force is not None:
        state.foot_force_w[..., 2] = contact_force
    cm = SimpleNamespace(command=torch.zeros(b, 3) if command is None else command)
    return SimpleNamespace(state=state, command_manager=cm, num_envs=b)


def test_base_lin_vel_is_expressed_in_the_base_frame():
    # base yawed +90 deg, moving along world +y: in the base frame that is +x
    env = fake_env([quat_axis_angle([0, 0, 1], math.pi / 2)], lin_vel_w=torch.tensor([[0.0, 1.0, 0.2]]))
    assert O.base_lin_vel(env)[0].tolist() == pytest.approx([1.0, 0.0, 0.2], abs=1e-6)


def test_projected_gravity_and_tilt_termination():
    # pitch by 30 deg about y: gravity in the base frame = (sin 30, 0, -cos 30)
    env = fake_env([quat_axis_angle([0, 1, 0], math.radians(30))])
    assert O.projected_gravity(env)[0].tolist() == pytest.approx([0.5, 0.0, -math.sqrt(3) / 2], abs=1e-6)
    assert float(R.flat_orientation(env)[0]) == pytest.approx(0.25, abs=1e-6)
    env = fake_env([quat_axis_angle([1, 0, 0], math.radians(44)), quat_axis_angle([1, 1, 0], math.radians(46))])
    assert T.bad_orientation(env, limit_deg=45.0).tolist() == [False, True]


def test_velocity_tracking_rewards():
    cmd = torch.tensor([[0.5, 0.0, 0.2]])
    env = fake_env([quat_axis_angle([0, 0, 1], 0.0)], lin_vel_w=torch.tensor([[0.2, 0.4, 0.1]]),
                   ang_vel_b=torch.tensor([[0.3, -0.4, 0.7]]), command=cmd)
    # e_xy = (-0.3, 0.4): ||e||^2 = 0.25 -> exp(-0.25 / 0.5)
    assert float(R.track_lin_vel_xy(env, sigma=0.5)) == pytest.approx(math.exp(-0.5), rel=1e-5)
    assert float(R.track_ang_vel_z(env, sigma=0.5)) == pytest.approx(math.exp(-0.25 / 0.5), rel=1e-5)
    assert float(R.lin_vel_z(env)) == pytest.approx(0.01, rel=1e-5)
    assert float(R.ang_vel_xy(env)) == pytest.approx(0.25, rel=1e-5)


def test_proprioceptive_height_uses_feet_in_contact_only():
    target = C.STANDING_BASE_HEIGHT - C.FOOT_RADIUS
    q = quat_axis_angle([0, 0, 1], 0.0)
    # feet at z = 0.05, 0.05 (contact), 0.2, 0.2 (swing): h = 0.40 - 0.05 = 0.35
    env = fake_env([q, q], foot_z=torch.tensor([0.05, 0.05, 0.2, 0.2]),
                   contact_force=torch.tensor([[50.0, 50.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]))
    h = R.proprioceptive_height(env)
    assert float(h[0]) == pytest.approx(0.35, abs=1e-6) and torch.isnan(h[1])
    r = R.base_height(env, target=0.33, sigma=0.1)
    assert float(r[0]) == pytest.approx(math.exp(-0.0004 / 0.02), rel=1e-4)
    assert float(r[1]) == 0.0  # no stance foot: undefined height, no reward
    assert float(R.base_height(env, target=0.34, sigma=0.1, alpha=0.015)[0]) == pytest.approx(1.0)
    assert target == pytest.approx(0.3115, abs=1e-3)


def test_joint_soft_limits_and_action_terms():
    env = fake_env([quat_axis_angle([0, 0, 1], 0.0)])
    assert float(R.joint_soft_limits(env)) == 0.0  # nominal pose is well inside
    lim = C.JOINT_RANGES[2]  # FL calf
    env.state.joint_pos[0, 2] = float(lim[1])  # at the upper limit: 5 % of the range outside the 90 % zone
    expected = (0.05 * (lim[1] - lim[0])) ** 2
    assert float(R.joint_soft_limits(env, soft_ratio=0.9)) == pytest.approx(expected, rel=1e-4)
    am = SimpleNamespace(raw_action=torch.ones(1, 28), prev_raw_action=torch.zeros(1, 28),
                         violation=torch.zeros(1, 28), applied_physical=torch.zeros(1, 28))
    am.violation[0, 3] = 2.0
    am.applied_physical[0, :4] = torch.tensor([0.5, 1.5, 2.0, 3.0])  # f: 0.5 below 1.0, 0.5 above 2.5
    env.action_manager = am
    assert float(R.action_rate(env)) == 28.0
    assert float(R.clipping_violation(env)) == 4.0
    assert float(R.clipping_violation(env, max_violation=3.0)) == 4.0  # inside the bound: the same
    am.violation[0, 5] = -50.0  # an action mean far out of range: 2500 unbounded, 3^2 bounded
    assert float(R.clipping_violation(env)) == 2504.0
    assert float(R.clipping_violation(env, max_violation=3.0)) == 13.0
    with pytest.raises(ValueError, match="max_violation must be > 0"):
        R.clipping_violation(env, max_violation=0.0)
    assert float(R.action_limit(env, "f", 1.0, 2.5)) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="allowed"):
        R.action_limit(env, "q", 0.0, 1.0)
