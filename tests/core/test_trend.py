"""Student's t (``core/stats.py``) against closed forms and printed tables, and the learning-curve trend
(``viz/learning_curve.py trend``) on series whose slope is known by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from torch.utils.tensorboard import SummaryWriter

from dls_quadruped.cli import UserError
from dls_quadruped.core.stats import t_cdf, t_quantile
from dls_quadruped.viz.learning_curve import main, trend


@pytest.mark.parametrize("x", [-7.0, -1.3, -0.2, 0.0, 0.4, 2.0, 25.0])
def test_t_cdf_against_closed_forms(x):
    assert t_cdf(x, 1) == pytest.approx(0.5 + math.atan(x) / math.pi, abs=1e-12)  # Cauchy
    assert t_cdf(x, 2) == pytest.approx(0.5 + x / (2.0 * math.sqrt(2.0 + x * x)), abs=1e-12)


def test_t_quantiles_of_the_printed_tables():
    for p, dof, q in [(0.975, 8, 2.306), (0.975, 1, 12.706), (0.995, 5, 4.032), (0.95, 30, 1.697), (0.975, 120, 1.980)]:
        assert t_quantile(p, dof) == pytest.approx(q, abs=5e-4)
    assert t_quantile(0.025, 3) == pytest.approx(-t_quantile(0.975, 3), abs=1e-10)
    assert t_quantile(0.975, 10**7) == pytest.approx(1.959964, abs=1e-5)  # the normal's
    with pytest.raises(ValueError, match="p must be in"):
        t_quantile(1.0, 3)
    with pytest.raises(ValueError, match="dof"):
        t_cdf(1.0, 0)


def _rows(values):
    return [{"iteration": i, "mean_reward": float(v)} for i, v in enumerate(values)]


def test_a_straight_line_is_rising_with_its_own_slope():
    t = trend(_rows(5.0 + 0.02 * np.arange(1000)), last=500)  # 2 per 100 iterations, no noise
    assert (t["first_iteration"], t["last_iteration"], len(t["block_means"])) == (500, 999, 10)
    assert t["block_means"][0] == pytest.approx(5.0 + 0.02 * 524.5)  # the mean of iterations 500-549
    assert t["slope_per_100"] == pytest.approx(2.0)
    assert t["ci95_per_100"][0] == pytest.approx(2.0) and t["reading"] == "rising"
    assert trend(_rows(-0.01 * np.arange(300)), last=300, block=100)["reading"] == "falling"


def test_the_interval_by_hand_on_noisy_blocks():
    # block means 0, 1, 0, 1, 1 (blocks of 2 iterations) at x = 0.5, 2.5, ..., 8.5; by hand: x centred -4, -2, 0, 2, 4,
    # y - 0.6 = -0.6, 0.4, -0.6, 0.4, 0.4, so the slope is (2.4 - 0.8 + 0.8 + 1.6) / 40 = 0.1 per iteration
    means = [0.0, 1.0, 0.0, 1.0, 1.0]
    values = np.repeat(means, 2)
    t = trend(_rows(values), last=10, block=2)
    x = np.arange(5) * 2 + 0.5
    slope, intercept = np.polyfit(x, means, 1)
    resid = np.array(means) - (slope * x + intercept)
    se = math.sqrt(resid @ resid / 3 / ((x - x.mean()) @ (x - x.mean())))
    assert t["slope_per_100"] == pytest.approx(10.0) and slope == pytest.approx(0.1)  # by hand and by numpy
    assert t["ci95_per_100"] == pytest.approx([100 * (slope - 3.182446 * se), 100 * (slope + 3.182446 * se)], rel=1e-5)
    assert t["reading"] == "flat"  # 0.1 per iteration with se 0.087: the interval holds 0


def test_bad_windows_are_refused(tmp_path):
    rows = _rows(np.arange(100))
    with pytest.raises(ValueError, match="multiple of block"):
        trend(rows, last=120, block=50)
    with pytest.raises(ValueError, match="at least 3 blocks"):
        trend(rows, last=100, block=50)
    with pytest.raises(ValueError, match="has 100 iterations"):
        trend(rows, last=150, block=50)
    with pytest.raises(SystemExit):  # argparse: a missing value
        main([str(tmp_path), "--csv", "a.csv", "--png", "a.png", "--trend"])
    for bad, match in [(["1", "2", "3"], "takes LAST and optionally BLOCK"), (["120", "50"], "multiple of block")]:
        with pytest.raises(UserError, match=match):
            main([str(tmp_path), "--csv", str(tmp_path / "a.csv"), "--png", str(tmp_path / "a.png"), "--trend", *bad])
    assert not (tmp_path / "a.csv").exists()  # refused before the run is read or anything written


def test_the_command_prints_the_trend_of_a_logged_run(tmp_path, capsys):
    with pytest.raises(SystemExit) as ex:
        main(["--help"])
    assert ex.value.code == 0 and "--trend LAST" in capsys.readouterr().out
    w = SummaryWriter(log_dir=str(tmp_path / "run"))
    for it in range(300):
        w.add_scalar("Train/mean_reward", 2.0 - 0.03 * it, it)  # -3 per 100 iterations
    w.close()
    main([str(tmp_path / "run"), "--csv", str(tmp_path / "c.csv"), "--png", str(tmp_path / "c.png"),
          "--trend", "200"])
    out = capsys.readouterr().out
    assert "iterations 100-299 (4 blocks of 50): slope -3.000 per 100 iterations" in out and "falling" in out
