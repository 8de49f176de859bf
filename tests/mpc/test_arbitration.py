"""Arbitration between warm-start groups (mpc/arbitration.py, issue 27 items 5, 7, 8): the switching cost
changes the winner only when the runner-up is within the penalty, the running group cost delays a switch as
worked out by hand, zero settings are the plain argmin, reset and fallbacks clear the memory, and bad values
are refused naming the value and what is allowed."""

from __future__ import annotations

import math

import pytest
import torch

from dls_quadruped.mpc import arbitration, warm_start
from dls_quadruped.mpc.arbitration import Memory, select
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.sampler import SamplingMPC

INF = math.inf


def test_switching_cost_by_hand() -> None:
    """Groups of 3 and 2 samples, s = 10; each row's winner worked out from its costs."""
    costs = torch.tensor([
        [5.0, 3.0, 4.0, 8.0, 1.5],       # J = (3, 1.5), was 0: runner-up 1.5 below, within 10 -> stays: sample 1
        [50.0, 40.0, 60.0, 20.0, 25.0],  # J = (40, 20), was 0: 20 below, beyond 10 -> switches: sample 3
        [7.0, 2.0, 9.0, 6.0, 2.5],       # J = (2, 2.5), no previous winner -> plain argmin: sample 1
        [1.0, 2.0, 3.0, 0.5, 4.0],       # J = (1, 0.5), was 1 and still best -> sample 3
        [20.0, 30.0, 25.0, 10.0, 11.0],  # J = (20, 10), was 0: exactly s below -> a tie stays: sample 0
        [9.0, 9.5, 9.9, 1.0, 2.0],       # J = (9, 1), was 1: group 0 is 8 worse, within 10 -> sample 3
        [INF, INF, INF, INF, INF],       # every sample diverged -> plain argmin: sample 0, +inf
    ])
    memory = Memory(torch.tensor([0, 0, -1, 1, 0, 1, 0]), torch.full((7, 2), math.nan, dtype=torch.float64))
    cost, index, average = select(costs, (3, 2), 10.0, 0.0, memory)
    assert index.tolist() == [1, 3, 1, 3, 0, 3, 0]
    assert cost.tolist() == [3.0, 20.0, 2.0, 0.5, 20.0, 1.0, INF]  # the winner's own cost, no penalty added
    assert average[:6].tolist() == [[3.0, 1.5], [40.0, 20.0], [2.0, 2.5], [1.0, 0.5], [20.0, 10.0], [9.0, 1.0]]
    # rows 0 and 4 are the ones the switching cost changed
    assert costs.min(dim=1).indices.tolist() == [4, 3, 1, 3, 3, 3, 0]


def test_running_group_cost_by_hand() -> None:
    """beta = 0.5, s = 2, groups of 1 sample each; J = (10, 10.5), then (10, 6) twice:
    solve 1: A = J = (10, 10.5), no previous winner -> group 0;
    solve 2: A = (10, 0.5 * 6 + 0.5 * 10.5 = 8.25), scores (10, 10.25) -> stays 0 (the plain argmin: 1);
    solve 3: A = (10, 0.5 * 6 + 0.5 * 8.25 = 7.125), scores (10, 9.125) -> switches to 1."""
    memory, winners, averages = None, [], []
    for row in ([10.0, 10.5], [10.0, 6.0], [10.0, 6.0]):
        _, index, average = select(torch.tensor([row]), (1, 1), 2.0, 0.5, memory)
        memory = Memory(index.clone(), average)  # the sample index is the group here (one sample per group)
        winners.append(int(index))
        averages.append(average[0].tolist())
    assert winners == [0, 0, 1]
    assert averages == [[10.0, 10.5], [10.0, 8.25], [10.0, 7.125]]


def test_running_group_cost_restarts_where_a_cost_is_not_finite() -> None:
    memory = Memory(torch.tensor([0, 0]), torch.tensor([[4.0, 5.0], [math.nan, 3.0]], dtype=torch.float64))
    costs = torch.tensor([[2.0, INF], [6.0, 1.0]])
    _, index, average = select(costs, (1, 1), 0.0, 0.75, memory)
    # robot 0: A = (0.25 * 2 + 0.75 * 4 = 3.5, inf: group 1 diverged); robot 1: A = (6: no finite memory,
    # 0.25 * 1 + 0.75 * 3 = 2.5) -> group 1
    assert average.tolist() == [[3.5, INF], [6.0, 2.5]]
    assert index.tolist() == [0, 1]


def _two_identical_groups(perturbed_standing, cfg: SamplerConfig, solves: int, b: int = 16, fused: bool = True,
                          reset_at: int = -1):
    """``solves`` solves of B robots, two groups around the same naive warm start (their winners differ by the
    noise alone); per solve: the (B, M) costs the arbitration saw and the result."""
    state, refs, phase = perturbed_standing(b, 3)
    mpc = SamplingMPC(cfg, seed=5)
    mpc.fused = fused
    default = warm_start.nominal_trot(b, cfg)
    seen = []
    arbitrate = mpc._arbitrate

    def spy(costs, props, best_cost, best_index):
        seen.append(costs.clone())
        return arbitrate(costs, props, best_cost, best_index)

    mpc._arbitrate = spy
    results = []
    for k in range(solves):
        if k == reset_at:
            mpc.reset(torch.tensor([1]))
        ws = mpc.naive_warm_start(default)
        results.append(mpc.solve(state, refs, [ws, ws], proportions=(0.5, 0.5), phase=phase))
        phase = (phase + 0.02) % 1.0
    return list(zip(seen, results, strict=True)), mpc


def test_switching_cost_changes_the_winner_only_within_the_penalty(perturbed_standing) -> None:
    """Real solves, s = 1000: each winner is the argmin of the sample costs plus s on every sample outside the
    previous winner's group (written per sample here, float64); both cases occur: a runner-up within s that
    the plain argmin would have taken, and one more than s below that takes over."""
    s, m = 1000.0, 200
    group = torch.arange(m) >= m // 2
    solves, _ = _two_identical_groups(perturbed_standing, SamplerConfig(num_samples=m, switching_cost=s), 6)
    prev = None
    kept = switched = 0
    for costs, result in solves:
        c = costs.double()
        if prev is not None:
            c = c + s * (group[None, :].long() != prev[:, None]).double()
        expected = c.argmin(dim=1)
        assert torch.equal(result.best_index, expected)
        assert torch.equal(result.best_cost, costs.gather(1, expected[:, None])[:, 0])  # the true cost
        if prev is not None:
            j, _ = arbitration.group_bests(costs, (m // 2, m // 2))
            gap = j.gather(1, prev[:, None])[:, 0] - j.gather(1, 1 - prev[:, None])[:, 0]  # > 0: the other is better
            kept += int(((gap > 0) & (gap <= s)).sum())
            switched += int((gap > s).sum())
            assert torch.equal(result.warm_start_index != prev, gap > s)
        prev = result.warm_start_index
    assert kept > 0 and switched > 0, (kept, switched)


def test_zero_settings_are_the_plain_argmin_bit_for_bit(perturbed_standing) -> None:
    """select with s = 0 and beta = 0 on real cost matrices, whatever the memory: torch's min, value and index;
    and a config with both 0 never arbitrates (the solve is the one without the fields)."""
    solves, _ = _two_identical_groups(perturbed_standing, SamplerConfig(num_samples=200, switching_cost=1.0), 3)
    for costs, result in solves:
        memory = Memory(result.warm_start_index.flip(0), torch.rand(16, 2, dtype=torch.float64))
        cost, index, _ = select(costs, (100, 100), 0.0, 0.0, memory)
        plain_cost, plain_index = costs.min(dim=1)
        assert torch.equal(cost, plain_cost) and torch.equal(index, plain_index)
    assert not SamplerConfig(switching_cost=0.0, group_cost_smoothing=0.0).arbitrates


def test_reset_and_fallback_clear_the_memory(perturbed_standing) -> None:
    cfg = SamplerConfig(num_samples=200, switching_cost=1000.0, group_cost_smoothing=0.5)
    solves, mpc = _two_identical_groups(perturbed_standing, cfg, 3, b=4, reset_at=2)
    mem = mpc._arbitration
    assert torch.equal(mem.winner, solves[-1][1].warm_start_index) and bool(torch.isfinite(mem.average).all())
    mpc.reset(torch.tensor([2]))
    assert mem.winner[2] == -1 and bool(mem.average[2].isnan().all())
    assert torch.equal(mem.winner[[0, 1, 3]], solves[-1][1].warm_start_index[[0, 1, 3]])
    mpc.reset()
    assert mpc._arbitration is None
    # robot 1 was reset before solve 2: that solve is its plain argmin
    costs, result = solves[2]
    assert int(result.best_index[1]) == int(costs[1].argmin())


def test_a_fallback_robot_has_no_previous_winner(perturbed_standing) -> None:
    cfg = SamplerConfig(num_samples=100, switching_cost=50.0)
    state, refs, phase = perturbed_standing(3, 1)
    mpc = SamplingMPC(cfg)
    ws = warm_start.nominal_trot(3, cfg)
    mpc.solve(state, refs, [ws, ws], proportions=(0.5, 0.5), phase=phase)
    state.com_vel_w[1, 0] = math.nan
    result = mpc.solve(state, refs, [ws, ws], proportions=(0.5, 0.5), phase=phase)
    assert result.fallback.tolist() == [False, True, False]
    assert mpc._arbitration.winner[1] == -1 and bool(mpc._arbitration.average[1].isnan().all())
    assert mpc._arbitration.winner[0] >= 0


@pytest.mark.parametrize("field, value, allowed", [
    ("switching_cost", -1.0, ">= 0 and finite"), ("switching_cost", math.nan, ">= 0 and finite"),
    ("switching_cost", math.inf, ">= 0 and finite"), ("switching_cost", True, ">= 0 and finite"),
    ("group_cost_smoothing", 1.0, "in [0, 1)"), ("group_cost_smoothing", -0.1, "in [0, 1)"),
    ("group_cost_smoothing", math.nan, "in [0, 1)"),
])
def test_bad_arbitration_values_are_refused_naming_them(field, value, allowed) -> None:
    with pytest.raises(ValueError) as err:
        SamplerConfig(**{field: value})
    message = str(err.value)
    assert len(message.splitlines()) == 1
    assert f"SamplerConfig.{field} must be {allowed}" in message and message.endswith(f"got {value!r}")
