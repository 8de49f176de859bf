"""Statistics of the 7.1 sweep scenarios against values worked out by hand, on synthetic recordings."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.eval import cot, gait, omni, speed, stairs
from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.rollout import Recording, record_episodes

DT = 0.02


def test_binomial_and_grouped_statistics_by_hand():
    b = M.binomial(8, 10)
    # Wilson, z = 1.96: centre (0.8 + z^2/20) / (1 + z^2/10), half z sqrt(0.016 + z^2/400) / (1 + z^2/10)
    z = M.Z95
    centre, half = (0.8 + z * z / 20) / (1 + z * z / 10), z * math.sqrt(0.016 + z * z / 400) / (1 + z * z / 10)
    assert b["rate"] == 0.8 and b["k"] == 8 and b["n"] == 10
    assert b["ci95"] == pytest.approx([centre - half, centre + half])
    assert b["ci95"] == pytest.approx([0.4902, 0.9433], abs=1e-4)  # tabulated Wilson interval of 8/10
    rates = M.grouped_rate(np.array([1, 1, 0, 0, 0, 1], dtype=bool), np.array([0, 0, 0, 1, 1, 1]), 3)
    assert [(r["k"], r["n"]) for r in rates] == [(2, 3), (1, 3), (0, 0)] and math.isnan(rates[2]["rate"])
    means = M.grouped_mean(np.array([1.0, 3.0, np.nan, 4.0]), np.array([0, 0, 0, 1]), 2)
    assert means[0]["mean"] == 2.0 and means[0]["n"] == 2
    assert means[0]["ci95"] == pytest.approx([2 - z * math.sqrt(2) / math.sqrt(2), 2 + z])  # sd sqrt(2), n 2
    assert means[1]["n"] == 1 and math.isnan(means[1]["ci95"][0])


def test_threshold_crossing_by_hand():
    levels = [1.0, 2.0, 3.0, 4.0]
    assert M.threshold_crossing(levels, [1.0, 0.95, 0.7, 0.2], 0.9) == pytest.approx(2.2)  # 2 + 0.05/0.25
    assert M.threshold_crossing(levels, [1.0, 1.0, 0.95, 0.9], 0.9) == 4.0                 # never below: grid end
    assert M.threshold_crossing(levels, [0.5, 1.0, 1.0, 1.0], 0.9) == 1.0                  # below at the first
    assert M.threshold_crossing(levels, [1.0, np.nan, 1.0, 1.0], 0.9) == pytest.approx(1.1)  # NaN counts as 0
    # the first drop counts, not a later recovery; the outermost edge ignores a low-level dip
    assert M.threshold_crossing(levels, [1.0, 0.8, 1.0, 1.0], 0.9) == pytest.approx(1.5)
    assert M.threshold_crossing(levels, [0.5, 1.0, 0.95, 0.7], 0.9, outermost=True) == pytest.approx(3.2)
    assert M.threshold_crossing(levels, [0.5, 1.0, 1.0, 1.0], 0.9, outermost=True) == 4.0
    assert M.threshold_crossing(levels, [0.5, 0.2, 0.0, 0.0], 0.9, outermost=True) == 1.0


def test_crossing_interval_shrinks_with_episodes_and_never_collapses_at_0_or_100_percent():
    levels = [1.0, 2.0, 3.0]
    point = M.threshold_crossing(levels, [1.0, 1.0, 0.0], 0.9)  # 2.1
    few = M.crossing_interval(levels, [10, 10, 0], [10, 10, 10], 0.9)
    many = M.crossing_interval(levels, [1000, 1000, 0], [1000, 1000, 1000], 0.9)
    assert few[0] < few[1] and few[0] <= point + 1e-9 and point - 1e-9 <= few[1]  # 0 % / 100 % are not certain
    assert many[1] - many[0] < few[1] - few[0] and many[0] <= point + 1e-9 <= many[1] + 2e-9
    assert many == pytest.approx([2.1, 2.1], abs=0.01)
    lo, hi = M.crossing_interval(levels, [4, 3, 1], [4, 4, 4], 0.9)
    assert lo < M.threshold_crossing(levels, [1.0, 0.75, 0.25], 0.9) <= hi and hi - lo > 0.3
    # a survival-vs-speed sweep of 16 episodes per speed (the base actor's): the interval holds the estimate
    speeds, k = [0.25 * i for i in range(1, 11)], np.array([16] * 5 + [15, 13, 2, 0, 0])
    point = M.threshold_crossing(speeds, k / 16, 0.9)
    lo, hi = M.crossing_interval(speeds, k, [16] * 10, 0.9)
    assert point == pytest.approx(1.575) and lo <= point <= hi


def recording(command, probes, valid=None, fell=None) -> Recording:
    T, E = next(iter(probes.values())).shape[:2]
    valid = np.ones((T, E), bool) if valid is None else valid
    fell = np.zeros(E, bool) if fell is None else np.asarray(fell)
    return Recording(command=np.asarray(command, float), probes=probes, valid=valid, fell=fell,
                     length=valid.sum(axis=0), step_dt=DT)


def test_speed_summary_of_a_known_response():
    """Two speeds x two episodes: the robot makes 90 % of the command; one episode at 1 m/s falls at 3 s."""
    cmd, group = speed.forward_commands((0.5, 1.0), 2)
    T = 250
    vel = np.zeros((T, 4, 3), np.float32)
    vel[..., 0] = 0.9 * cmd[:, 0]
    vel[:100, :, 0] = 0.0   # the first 2 s (the settle) are not counted
    valid = np.ones((T, 4), bool)
    valid[150:, 3] = False  # env 3 fell after 3 s: its 1 s after the settle counts
    res = speed.summarize(recording(cmd, {"velocity": vel}, valid, fell=[0, 0, 0, 1]), group, (0.5, 1.0))
    assert [r["survival"]["k"] for r in res["per_speed"]] == [2, 1]
    assert res["per_speed"][0]["achieved_v_x"]["mean"] == pytest.approx(0.45)
    assert res["per_speed"][1]["achieved_v_x"]["mean"] == pytest.approx(0.9)
    assert res["per_speed"][1]["achieved_over_commanded"]["mean"] == pytest.approx(0.9)
    assert res["survival_crossing"]["speed"] == pytest.approx(0.5 + 0.1 / 0.5 * 0.5)  # rates 1.0 -> 0.5 at 0.9
    assert res["max_achieved_v_x"]["command_v_x"] == 1.0


def test_cost_of_transport_matches_the_reward_kernel():
    """A constant gait: the episode CoT (energy / m g distance) is the kernel's instantaneous CoT."""
    from dls_quadruped.envs.mdp.kernels import cost_of_transport

    tau = torch.tensor([[10.0, -5.0, 2.0, 0.0]])
    qd = torch.tensor([[3.0, 2.0, -1.0, 7.0]])
    weight, v = 240.0, 0.8
    env = SimpleNamespace(state=SimpleNamespace(joint_torque=tau, joint_vel=qd))
    power = float(S.PROBES["power"](env))
    # by hand: max(30 + 30, 0) + max(-10 + 7.5, 0) + max(-2 + 1.2, 0) + 0 = 60 W
    assert power == pytest.approx(60.0)
    T, E = 10, 2
    ok = np.ones((T, E), bool)
    ok[5:, 1] = False  # the half that is masked out has nonsense
    P = np.full((T, E), power)
    P[5:, 1] = 1e6
    got = cot.episode_cot(P, np.full((T, E), v), ok, weight)
    kernel = float(cost_of_transport(tau, qd, torch.tensor([v]), weight, alpha=S.POWER_ALPHA))
    assert got == pytest.approx([kernel, kernel]) and kernel == pytest.approx(60.0 / (weight * v))
    assert math.isnan(cot.episode_cot(P, np.zeros((T, E)), ok, weight)[0])  # no distance: no CoT


def trot(T: int, freq: float, duty: float = 0.5) -> np.ndarray:
    """(T, 1, 4) contacts of an ideal trot: FL and RR in phase, FR and RL half a cycle later."""
    t = np.arange(T) * DT
    phase = (t[:, None] * freq + np.array([0.0, 0.5, 0.5, 0.0])) % 1.0
    return (phase < duty).astype(np.float32)[:, None, :]


def test_gait_figures_of_an_ideal_trot():
    c = trot(500, 2.0)  # 10 s, 2 Hz, duty 0.5: 20 touch-downs per leg
    ok = np.ones((500, 1), bool)
    assert gait.touchdown_rate(c, ok, DT)[0] == pytest.approx([2.0] * 4, abs=0.11)  # 19-20 edges in 9.98 s
    sync = gait.pair_sync(c, ok)
    assert sync["diagonal"][0] == 1.0 and sync["lateral"][0] == 0.0
    assert sync["front"][0] == 0.0 and sync["rear"][0] == 0.0
    assert gait.touchdown_rate(c, ok, DT, 3)[0] == pytest.approx([2.0] * 4, abs=0.11)  # 12-step swings pass
    bouncing = c.copy()
    bouncing[1::25] = 1 - bouncing[1::25]  # one flicker per half cycle, on each leg
    assert (gait.touchdown_rate(bouncing, ok, DT)[0] > 3.5).all()
    assert gait.touchdown_rate(bouncing, ok, DT, 3)[0] == pytest.approx([2.0] * 4, abs=0.11)
    ok[250:] = False  # half the time: half the touch-downs, same rate
    assert gait.touchdown_rate(c, ok, DT)[0] == pytest.approx([2.0] * 4, abs=0.21)
    cmd, group = speed.forward_commands((0.5,), 1)
    rec = recording(cmd, {"contact": np.repeat(c, 1, axis=1), "freq": np.full((500, 1, 4), 2.0, np.float32),
                          "duty": np.full((500, 1, 4), 0.5, np.float32)})
    res = gait.summarize(rec, group, (0.5,), settle_s=2.0)
    row = res["per_speed"][0]
    assert row["f_policy"]["mean"] == pytest.approx(2.0)
    assert row["duty_contacts"]["mean"] == pytest.approx(0.5, abs=0.01)
    d = res["diagrams"][0]
    assert d["episode"] == 0 and len(d["contact"]["FL"]) == round(gait.WINDOW_S / DT)
    assert d["contact"]["FL"] == d["contact"]["RR"] != d["contact"]["FR"]


def test_omni_grid_and_success_rule():
    cmd = omni.grid_commands((0, 90, 180), (0.5, 1.0))
    np.testing.assert_allclose(cmd, [[0.5, 0, 0], [1.0, 0, 0], [0, 0.5, 0], [0, 1.0, 0], [-0.5, 0, 0], [-1.0, 0, 0]],
                               atol=1e-12)
    full, group = S.repeat_conditions(cmd, 2)
    assert full.shape == (12, 3) and group.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5]
    # achieved = command + an error of 0.2 m/s across it: success where 0.2 <= 0.25 |cmd| (|cmd| = 1) only
    T = 200
    vel = np.zeros((T, 12, 3), np.float32)
    vel[..., :2] = full[:, :2]
    vel[..., 0] += 0.2 * (np.abs(full[:, 1]) > 1e-9)  # cos(90 deg) is 6e-17, not 0
    vel[..., 1] += 0.2 * (np.abs(full[:, 0]) > 1e-9)
    rec = recording(full, {"velocity": vel}, fell=[0] * 11 + [1])
    ok = omni.success_flags(rec, settle_s=1.0)
    assert ok.tolist() == [False, False, True, True] * 2 + [False, False, True, False]
    res = omni.summarize(rec, group, (0, 90, 180), (0.5, 1.0), settle_s=1.0)
    assert [c["success"]["rate"] for c in res["cells"]] == [0.0, 1.0, 0.0, 1.0, 0.0, 0.5]
    # direction 0: success [0, 1] -> its edge is beyond the grid; 180: survival [1, 0.5]
    assert res["isolines"][0]["success"]["beyond_grid"] and res["isolines"][0]["success"]["magnitude"] == 1.0
    assert not res["isolines"][0]["success"]["below_grid"] and res["isolines"][0]["survival"]["beyond_grid"]
    assert res["isolines"][2]["survival"]["magnitude"] == pytest.approx(0.5 + 0.1 / 0.5 * 0.5)


def test_stairs_climbed_fraction_by_hand():
    ground = np.array([[-0.6, -0.6], [-0.4, -0.5], [0.0, -0.5], [0.0, 9.0]])  # (T, E); 9 m after env 1 ended
    valid = np.array([[1, 1], [1, 1], [1, 1], [1, 0]], bool)
    frac = stairs.climbed_fraction(ground, valid, np.array([-0.6, -0.6]), np.array([0.6, 0.6]))
    assert frac == pytest.approx([1.0, 1 / 6])


class CountingEnv:
    """Stand-in env: env 1 ends at step 3 (a fall); probes read the step counter."""

    num_envs, step_dt, max_episode_length = 2, DT, 5

    def __init__(self):
        self.k = 0
        self.command_manager = SimpleNamespace(command=torch.tensor([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0]]))

    def get_observations(self):
        return TensorDict({"policy": torch.zeros(2, 1)}, batch_size=[2])

    def step(self, actions):
        self.k += 1
        dones = torch.tensor([self.k == 5, self.k == 3])
        return self.get_observations(), torch.zeros(2), dones.long(), {"time_outs": torch.tensor([self.k == 5, False])}


def test_record_episodes_masks_what_follows_an_end():
    rec = record_episodes(CountingEnv(), lambda obs: torch.zeros(2, 1),
                          {"k": lambda env: torch.full((2, 2), float(env.k))})
    assert rec.probes["k"].shape == (5, 2, 2) and rec.probes["k"][2, 0, 0] == 3.0
    assert rec.valid[:, 0].tolist() == [True] * 4 + [False]  # the time-out step's read is the next episode's
    assert rec.valid[:, 1].tolist() == [True, True, False, False, False]
    assert rec.fell.tolist() == [False, True] and rec.length.tolist() == [5, 3]
