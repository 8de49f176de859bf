"""Closed-loop metrics against hand-computed values (issue 12 item 7): the initial cost of known
states from Table 9's weights, the cost of transport and the medians of a recorded trace."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.closed_loop.loop import ClosedLoopTraces, InitialCostProbe
from dls_quadruped.closed_loop.metrics import cost_of_transport, summarize
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.robots.aliengo import constants as C


def _state(base_z: float, vel_w=(0.0, 0.0, 0.0), yaw: float = 0.0, ang_b=(0.0, 0.0, 0.0)) -> RobotState:
    b = 1
    quat = torch.tensor([[np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]], dtype=torch.float32)
    z = lambda *s: torch.zeros(b, *s)
    feet = torch.tensor([[[0.24, 0.13, 0.02], [0.24, -0.13, 0.02], [-0.24, 0.13, 0.02], [-0.24, -0.13, 0.02]]])
    return RobotState(base_pos_w=torch.tensor([[0.3, -0.2, float(base_z)]], dtype=torch.float32), base_quat_w=quat,
                      base_lin_vel_w=torch.tensor([vel_w]), base_ang_vel_b=torch.tensor([ang_b]),
                      joint_pos=z(12), joint_vel=z(12), joint_torque=z(12), foot_pos_w=feet, foot_vel_w=z(4, 3),
                      foot_force_w=z(4, 3), phase=z(4), contact_cmd=torch.ones(b, 4),
                      base_contact=torch.zeros(b, dtype=torch.bool), time=z(),
                      diverged=torch.zeros(b, dtype=torch.bool))


def test_initial_cost_of_known_states() -> None:
    probe = InitialCostProbe(SamplerConfig())
    stand = torch.zeros(1, 3)
    # level base at the height target, at rest, commanded to stand: nothing to pay
    assert float(probe(_state(C.BASE_HEIGHT_TARGET), stand)) == pytest.approx(0.0, abs=1e-6)
    # 1 cm too high: Q_z (0.01)^2 = 111 500 x 1e-4 = 11.15 (the CoM moves with the base), all of it the z term
    assert float(probe(_state(C.BASE_HEIGHT_TARGET + 0.01), stand)) == pytest.approx(11.15, rel=1e-4)
    terms = probe.terms(_state(C.BASE_HEIGHT_TARGET + 0.01), stand)[0]
    assert float(terms[0]) == pytest.approx(11.15, rel=1e-4) and float(terms[1:].abs().max()) < 1e-6
    # commanded 0.5 m/s forward while standing still: Q_vx 0.5^2 = 5 000 x 0.25 = 1 250
    cost = float(probe(_state(C.BASE_HEIGHT_TARGET), torch.tensor([[0.5, 0.0, 0.0]])))
    assert cost == pytest.approx(1250.0, rel=1e-5)
    # the command is in the heading frame: facing +y (yaw 90 deg) and moving at 0.5 m/s along +y is on target
    moving = _state(C.BASE_HEIGHT_TARGET, vel_w=(0.0, 0.5, 0.0), yaw=np.pi / 2)
    assert float(probe(moving, torch.tensor([[0.5, 0.0, 0.0]]))) == pytest.approx(0.0, abs=1e-3)
    # yaw rate 0.2 rad/s short of the command: Q_wz 0.2^2 = 200 x 0.04 = 8 (the CoM offset adds a
    # velocity omega x c_b that costs 5 000 (|omega x c_b|^2) ~ 5e-3 more)
    spin = _state(C.BASE_HEIGHT_TARGET, ang_b=(0.0, 0.0, 0.3))
    assert float(probe(spin, torch.tensor([[0.0, 0.0, 0.5]]))) == pytest.approx(8.0, abs=0.02)
    by_term = probe.terms(spin, torch.tensor([[0.0, 0.0, 0.5]]))[0]
    assert float(by_term[8]) == pytest.approx(8.0, rel=1e-4)  # the yaw-rate term
    assert float(by_term.sum()) == pytest.approx(float(probe(spin, torch.tensor([[0.0, 0.0, 0.5]]))), rel=1e-5)


def _traces(reward: np.ndarray, power: np.ndarray, speed: np.ndarray, fell: np.ndarray) -> ClosedLoopTraces:
    t, e = reward.shape
    nan = np.full((t, e), np.nan, np.float32)
    solves = np.full((t, 1, e), np.nan, np.float32)
    return ClosedLoopTraces(
        controller="x", command=np.zeros((e, 3)), reward=reward, initial_cost=nan,
        initial_cost_terms=np.full((t, e, 9), np.nan), vel_error=nan, power=power,
        speed=speed, base_vel=np.zeros((t, e, 3)), rollout_cost=solves, rollout_input_cost=solves,
        mpc_initial_cost=solves, step_costs=np.full((t, 1, e, 10), np.nan),
        step_input_costs=np.full((t, 1, e, 10), np.nan), winner=np.full((t, 1, e), -1), fell=fell,
        length=np.full(e, t), qpos=np.zeros((t, 1, 19)), mpc_fallbacks=0, student_fallbacks=0, step_dt=0.5)


def test_cost_of_transport_and_medians_by_hand() -> None:
    # 6 steps of 0.5 s, 2 episodes; the settle (1 s) drops the first two steps
    power = np.array([[999, 999], [999, 999], [100, 300], [200, 300], [300, np.nan], [400, np.nan]], float)
    speed = np.array([[9, 9], [9, 9], [0.5, 1.0], [0.5, 1.0], [0.5, np.nan], [0.5, np.nan]], float)
    reward = np.array([[1.0, 2.0], [2.0, 3.0], [3.0, 4.0], [4.0, np.nan], [5.0, np.nan], [6.0, np.nan]], float)
    tr = _traces(reward, power, speed, fell=np.array([False, True]))
    mg = C.TOTAL_MASS * C.GRAVITY
    cot = cost_of_transport(tr, settle_s=1.0)
    np.testing.assert_allclose(cot, [250.0 / (mg * 0.5), 300.0 / (mg * 1.0)], rtol=1e-12)
    s = summarize(tr, settle_s=1.0)
    # per episode first: episode 0 (1..6) median 3.5, episode 1 (2, 3, 4 until its fall) median 3;
    # across the two episodes: median 3.25, quartiles 3.125 and 3.375 (linear interpolation)
    r = s["rl_reward"]
    assert (r["median"], r["q1"], r["q3"], r["n"]) == (3.25, 3.125, 3.375, 2)
    assert s["per_episode"]["rl_reward"] == [[3.5, 3.0]]
    assert 3.0 <= r["ci95"][0] <= r["ci95"][1] <= 3.5  # a bootstrap median of {3, 3.5}
    # the thesis's pooled statistic: values 1, 2, 3, 4, 5, 6, 2, 3, 4: median 3, quartiles 2 and 4
    p = r["pooled"]
    assert p["median"] == 3.0 and p["q1"] == 2.0 and p["q3"] == 4.0 and p["n"] == 9
    assert s["survival"]["survived"] == 1 and s["survival"]["n"] == 2 and s["episodes"] == 2
    assert "rollout_cost" not in s  # no MPC in these traces


def test_state_only_rollout_cost_and_sampler_replicas() -> None:
    """Two sampler seeds (replicas) on two episodes: env s E + e; the rollout cost reported is J minus its
    input part, per episode first."""
    t, e = 4, 4
    reward = np.ones((t, e))
    tr = _traces(reward, np.ones((t, e)), np.ones((t, e)), fell=np.array([False, False, True, False]))
    full = np.array([[10.0, 20.0, 30.0, 40.0]] * t)[:, None, :]  # (T, 1, E)
    tr.rollout_cost = full.astype(np.float32)
    tr.rollout_input_cost = np.full_like(tr.rollout_cost, 4.0)
    tr.mpc_initial_cost = np.ones_like(tr.rollout_cost)
    tr.step_costs = np.repeat(tr.rollout_cost[..., None] / 10, 10, axis=-1)
    tr.step_input_costs = np.full_like(tr.step_costs, 0.4)
    s = summarize(tr, settle_s=0.0, replicas=2)
    assert s["episodes"] == 2 and s["replicas"] == 2
    assert s["per_episode"]["rollout_cost"] == [[6.0, 16.0], [26.0, 36.0]]  # state-only: J - 4
    assert s["per_episode"]["rollout_cost_full"] == [[10.0, 20.0], [30.0, 40.0]]
    assert s["rollout_cost"]["median"] == 21.0 and s["rollout_cost_full"]["median"] == 25.0
    np.testing.assert_allclose(s["horizon_cost"][0]["median"], 2.5 - 0.4, rtol=1e-6)
    assert s["per_episode"]["survived"] == [[1.0, 1.0], [0.0, 1.0]] and s["survival"]["rate"] == 0.75
    from dls_quadruped.eval.metrics import wilson_interval

    assert s["survival"]["ci95_episodes"] == list(wilson_interval(1.5, 2))  # 75 % of 2 independent episodes
    with pytest.raises(ValueError, match="replicas must divide"):
        summarize(tr, replicas=3)


def test_initial_cost_terms_per_episode_add_up_to_the_total() -> None:
    """Per-episode means of each term (NaN after a fall left out) sum to the total's mean, by hand: episode 0
    z = (1 + 3) / 2 = 2, vx = (2 + 2) / 2 = 2, total (3 + 5) / 2 = 4; episode 1 ends after its first step."""
    t, e = 2, 2
    terms = np.zeros((t, e, 9))
    terms[:, 0, 0] = [1.0, 3.0]  # z
    terms[:, 0, 1] = [2.0, 2.0]  # vx
    terms[0, 1, 0], terms[1, 1] = 7.0, np.nan
    tr = _traces(np.ones((t, e)), np.ones((t, e)), np.ones((t, e)), fell=np.array([False, True]))
    tr.initial_cost_terms = terms
    tr.initial_cost = terms.sum(-1)
    s = summarize(tr, settle_s=0.0)
    pe = s["per_episode"]
    assert pe["initial_term_z"][0] == [2.0, 7.0] and pe["initial_term_vx"][0] == [2.0, 0.0]
    assert pe["initial_cost_mean"][0] == [4.0, 7.0]
    total = sum(np.array(pe[f"initial_term_{n}"]) for n in ("z", "vx", "vy", "vz", "roll", "pitch", "roll_rate",
                                                             "pitch_rate", "yaw_rate"))
    np.testing.assert_allclose(total, pe["initial_cost_mean"])


def test_rollout_cost_terms_per_episode_over_the_recorded_solves() -> None:
    """The chosen sample's state rollout cost by term, recorded on some solves only (NaN on the others, +inf on a
    fallback): per-episode means over the recorded finite solves, by hand. Episode 0: solves 0 and 2 recorded,
    z = (1 + 3) / 2 = 2, vz = (4 + 0) / 2 = 2, total 4; episode 1: solve 0 a fallback (+inf), solve 2 z = 5."""
    t, e = 4, 2
    tr = _traces(np.ones((t, e)), np.ones((t, e)), np.ones((t, e)), fell=np.array([False, False]))
    tr.rollout_cost = np.full((t, 1, e), 50.0, np.float32)
    tr.rollout_input_cost = np.zeros_like(tr.rollout_cost)
    terms = np.full((t, 1, e, 9), np.nan)
    terms[[0, 2], 0, 0] = 0.0
    terms[0, 0, 0, 0], terms[2, 0, 0, 0], terms[0, 0, 0, 3] = 1.0, 3.0, 4.0
    terms[0, 0, 1] = np.inf
    terms[2, 0, 1] = 0.0
    terms[2, 0, 1, 0] = 5.0
    tr.rollout_state_terms = terms
    pe = summarize(tr, settle_s=0.0)["per_episode"]
    assert pe["rollout_term_z"][0] == [2.0, 5.0] and pe["rollout_term_vz"][0] == [2.0, 0.0]
    assert pe["rollout_terms_mean"][0] == [4.0, 5.0]
    tr.rollout_state_terms = None  # traces without terms (older runs): no rollout_term keys
    assert not any(k.startswith("rollout_term") for k in summarize(tr, settle_s=0.0)["per_episode"])
