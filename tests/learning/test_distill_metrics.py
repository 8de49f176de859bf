"""SP (eq. 7.2.2) and test MSE (eq. 7.2.1) on numbers worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_bench import table7_steps
from dls_quadruped.learning.distill_metrics import (
    held_out_mse,
    simulation_performance,
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
