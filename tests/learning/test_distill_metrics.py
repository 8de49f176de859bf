"""SP (eq. 7.2.2) and test MSE (eq. 7.2.1) on numbers worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_bench import table7_steps
from dls_quadruped.learning.distill_metrics import (
    episode_returns,
    held_out_mse,
    mse_over_seeds,
    simulation_performance,
    slot_returns,
    sp_difference,
    sp_over_seeds,
    survival,
)


def test_sp_rescales_between_untrained_and_expert():
    r0 = np.array([1.0, 2.0, 3.0])  # sum 6
    exp = np.array([11.0, 12.0, 13.0])  # sum 36
    stud = np.array([8.0, 9.0, 4.0])  # sum 21 -> (21 - 6) / (36 - 6) = 0.5
    out = simulation_performance(stud, exp, r0)
    assert out["sp"] == pytest.approx(0.5) and out["episodes"] == 3
    assert out["ci95"][0] <= 0.5 <= out["ci95"][1]
    assert simulation_performance(exp, exp, r0)["sp"] == pytest.approx(1.0)
    assert simulation_performance(r0, exp, r0)["sp"] == pytest.approx(0.0)
    same = simulation_performance(exp - 1.0, exp, r0)  # every episode 1 below the expert: a tight interval
    assert same["ci95"][1] - same["ci95"][0] < 0.05
    with pytest.raises(ValueError, match="three"):
        simulation_performance(stud[:2], exp, r0)


def test_survival_has_a_wilson_interval():
    out = survival(np.array([True] * 9 + [False]))
    assert out["rate"] == pytest.approx(0.9) and out["episodes"] == 10
    assert 0.55 < out["ci95"][0] < 0.9 < out["ci95"][1] <= 1.0


def test_mse_is_the_mean_over_rows_and_outputs(tmp_path):
    ds = DiskDataset.create(tmp_path / "t", 2, 3, capacity=4)
    ds.append(torch.zeros(4, 2), torch.arange(12, dtype=torch.float32).view(4, 3))
    # a net that predicts 1 everywhere: mean of (k - 1)^2 for k = 0..11 = 386 / 12
    assert held_out_mse(lambda obs: torch.ones(len(obs), 3), ds, batch=3) == pytest.approx(386 / 12)


def test_table7_gradient_step_count():
    # dataset 100, 200, 250 (capped) rows at batch 64: 2 + 4 + 4 steps
    assert table7_steps(epochs=3, per_epoch=100, cap=250, batch=64) == 10
    # Table 7: sum over 30 epochs of ceil(min(800k, 80k (i + 1)) / 64)
    assert table7_steps() == sum(-(-min(800_000, 80_000 * (i + 1)) // 64) for i in range(30)) == 318_750


def test_sp_over_seeds_by_hand():
    """Expert 1 and r_0 0 in every episode; seed k returns c_k in every episode, so SP_k = c_k and
    nothing varies over episodes: the point is the mean 0.6, each seed's own interval is its point,
    and the combined interval is [min, max] of the seeds (a resample of all three seeds equal to the
    smallest has probability 1/27 = 3.7 % > 2.5 %, so the 2.5 % percentile is that smallest mean)."""
    c = np.array([0.4, 0.6, 0.8])
    r = np.repeat(c[:, None], 5, axis=1)
    out = sp_over_seeds(r, np.ones(5), np.zeros(5))
    assert out["sp"] == pytest.approx(0.6) and out["seeds"] == 3 and out["episodes"] == 5
    assert [p["sp"] for p in out["per_seed"]] == pytest.approx(c.tolist())
    assert out["per_seed"][0]["ci95"] == pytest.approx([0.4, 0.4])
    assert out["ci95"] == pytest.approx([0.4, 0.8])
    one = sp_over_seeds(r[:1], np.ones(5), np.zeros(5))  # one seed: the seed level adds nothing
    assert one["ci95"] == pytest.approx([0.4, 0.4])


def test_sp_over_seeds_holds_the_episode_spread_too():
    """Identical seeds, episodes that differ: the combined interval is the per-seed episode bootstrap's
    width (not zero), so a table with one seed per row understated nothing but the seed spread."""
    rng = np.random.default_rng(1)
    exp, r0 = 30 + rng.normal(0, 1, 40), rng.normal(0, 1, 40)
    stud = np.tile(exp - 3 + rng.normal(0, 3, 40), (3, 1))
    out = sp_over_seeds(stud, exp, r0)
    single = simulation_performance(stud[0], exp, r0)
    assert out["sp"] == pytest.approx(single["sp"])
    assert out["ci95"][1] - out["ci95"][0] == pytest.approx(single["ci95"][1] - single["ci95"][0], rel=0.3)
    with pytest.raises(ValueError, match="returns must be"):
        sp_over_seeds(stud, exp[:3], r0)


def test_sp_difference_of_paired_settings():
    """Episodes vary, seeds do not, and b is a plus 1 (0.1 SP) in every episode: resampling the episodes
    *jointly* gives -0.1 every time (a zero-width interval); unpaired it would not."""
    exp, r0 = np.full(6, 10.0), np.zeros(6)
    a = np.tile([2.0, 6, 9, 3, 5, 7], (2, 1))
    out = sp_difference(a, a + 1.0, exp, r0, r0)
    assert out["difference"] == pytest.approx(-0.1) and out["ci95"] == pytest.approx([-0.1, -0.1])
    seeds_differ = sp_difference(a + np.array([[0.0], [2.0]]), a, exp, r0, r0)  # a's two seeds 0.2 SP apart
    assert seeds_differ["difference"] == pytest.approx(0.1) and seeds_differ["ci95"] == pytest.approx([0.0, 0.2])


def test_mse_over_seeds_by_hand():
    """Two seeds, episodes of 1 and 3 windows with per-window errors summing to (2, 6) and (4, 4):
    MSE_0 = 8 / 4 = 2, MSE_1 = 8 / 4 = 2, mean 2 (windows, not episodes, are weighted equally)."""
    out = mse_over_seeds(np.array([[2.0, 6.0], [4.0, 4.0]]), np.array([1.0, 3.0]))
    assert out["mse"] == pytest.approx(2.0) and out["per_seed"] == pytest.approx([2.0, 2.0])
    assert out["windows"] == 4 and out["ci95"][0] <= 2.0 <= out["ci95"][1]


@pytest.fixture
def falling_env(scripted_env):
    """4 robots, episodes of 3, 10, 10, 5 steps with a 10-step time-out: robots 1 and 2 time out, 0 and 3 fall;
    robot e earns e + 1 per step."""
    class Falling(scripted_env):
        max_episode_length = 10

        def step(self, actions):
            obs, _, dones, _ = super().step(actions)
            time_outs = dones.bool() & (self.lengths >= self.max_episode_length)
            return obs, torch.arange(1.0, 5.0), dones, {"time_outs": time_outs}

    return Falling([3, 10, 10, 5])


def test_slot_returns_and_the_recorded_slot_by_hand(falling_env, tag_expert):
    zeros = lambda obs: torch.zeros(len(obs), 28)
    res = slot_returns(falling_env, [zeros, tag_expert], seed=3, keys=torch.arange(4), record=1)
    np.testing.assert_array_equal(res["return"], [[1.0 * 3, 2.0 * 10], [3.0 * 10, 4.0 * 5]])
    assert res["return"].dtype == np.float64
    assert res["survived"].tolist() == [[False, True], [True, False]]
    rec = res["record"]  # slot 1 = robots 2 and 3, driven by the tag expert
    assert rec.length.tolist() == [10, 5] and rec.seed == 3 and rec.obs.shape == (2, 10, 3)
    assert rec.obs[1, :5, 1].tolist() == [0, 1, 2, 3, 4] and not rec.obs[1, 5:].any()  # zeros after the fall
    torch.testing.assert_close(rec.actions[1, :5], tag_expert(rec.obs[1, :5]), rtol=0, atol=0)
    assert falling_env.applied[0][:2].abs().sum() == 0  # slot 0's robots got its own policy's actions
    with pytest.raises(ValueError, match="do not split into 3 slots"):
        slot_returns(falling_env, [zeros] * 3, seed=3, keys=torch.arange(4))


def test_episode_returns_one_batch_per_seed(falling_env, tag_expert):
    res = episode_returns(falling_env, tag_expert, seeds=[1, 2])
    np.testing.assert_array_equal(res["return"], [3.0, 20.0, 30.0, 20.0] * 2)
    assert res["survived"].tolist() == [False, True, True, False] * 2
