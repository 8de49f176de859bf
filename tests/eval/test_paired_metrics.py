"""Intervals over seeds and episodes, and paired differences, on hand-made values."""

from __future__ import annotations

import numpy as np
import pytest

from dls_quadruped.eval import metrics as M


def test_paired_difference_by_hand():
    a = np.array([3.0, 5.0, 7.0, 9.0])
    b = np.array([1.0, 2.0, 3.0, 4.0])
    d = M.paired_difference(a, b, draws=4000)
    assert d["mean"] == pytest.approx(3.5)                  # differences 2, 3, 4, 5
    assert d["relative"] == pytest.approx(14.0 / 10.0)       # sum d / sum b
    assert 2.0 <= d["ci95"][0] < 3.5 < d["ci95"][1] <= 5.0   # a bootstrap mean of {2, 3, 4, 5}
    assert d["episodes"] == 4
    # pairing matters: the same values with a constant offset have a zero-width interval
    same = M.paired_difference(b + 1.0, b)
    assert same["mean"] == 1.0 and same["ci95"] == [1.0, 1.0]
    # unpaired spread would be wide: the episodes' own spread (1 .. 4) does not enter the paired interval


def test_paired_difference_with_seeds_and_missing_episodes():
    a = np.array([[1.0, 2.0, np.nan], [3.0, 4.0, np.nan]])  # 2 seeds, episode 2 missing
    b = np.array([0.0, 0.0, 5.0])                          # one run (no seed)
    d = M.paired_difference(a, b)
    assert d["episodes"] == 2 and d["mean"] == pytest.approx(2.5)  # per-episode seed means 2 and 3
    # seeds resampled too: an all-seed-0 draw gives episode values 1, 2 (mean 1.5), all-seed-1 3, 4
    assert 1.0 <= d["ci95"][0] < 2.5 < d["ci95"][1] <= 4.0
    with pytest.raises(ValueError, match="same episodes"):
        M.paired_difference(np.zeros(3), np.zeros(4))


def test_bootstrap_ci_of_identical_values_is_a_point_and_grows_with_spread():
    assert M.bootstrap_ci(np.full((3, 5), 2.0)) == [2.0, 2.0]
    narrow = M.bootstrap_ci(np.array([1.0, 1.1, 0.9, 1.0, 1.05, 0.95]), np.nanmean)
    wide = M.bootstrap_ci(np.array([1.0, 3.0, -1.0, 1.0, 2.0, 0.0]), np.nanmean)
    assert narrow[1] - narrow[0] < wide[1] - wide[0]
    s = M.episode_summary(np.array([[1.0, 2.0, 3.0], [2.0, 3.0, 4.0]]))
    assert s["median"] == 2.5 and s["n"] == 6 and s["mean"] == pytest.approx(2.5)
    # the seed level: two seeds that disagree give a wider interval than two that agree
    agree = M.bootstrap_ci(np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]]), np.nanmean)
    disagree = M.bootstrap_ci(np.array([[0.0, 1.0, 2.0], [2.0, 3.0, 4.0]]), np.nanmean)
    assert agree[1] - agree[0] < disagree[1] - disagree[0]


def test_paired_seeds_resample_the_same_student_in_both_rows():
    """Rows are students whose level differs (10, 20, 30) and a = b + 1 for each student on every episode: paired
    by student the difference is exactly +1 in every resample; resampled independently the students' levels
    leak in (a draw of student 0 for a against student 2 for b gives 11 - 30)."""
    b = np.array([[10.0, 11.0, 12.0, 13.0], [20.0, 21.0, 22.0, 23.0], [30.0, 31.0, 32.0, 33.0]])
    a = b + 1.0
    joint = M.paired_difference(a, b, paired_seeds=True)
    assert joint["mean"] == pytest.approx(1.0) and joint["ci95"] == pytest.approx([1.0, 1.0])
    apart = M.paired_difference(a, b)
    assert apart["mean"] == pytest.approx(1.0) and apart["ci95"][0] < -3.0 and apart["ci95"][1] > 5.0
    with pytest.raises(ValueError, match="same seeds"):
        M.paired_difference(a, b[:2], paired_seeds=True)


def test_paired_median_is_robust_to_one_stumbling_episode():
    """Differences 1 .. 8 and one episode where b stumbled (-100): the mean is dragged to (36 - 100) / 9, the
    median of {-100, 1, ..., 8} is 4. A resample's median reaches -100 only if it draws the stumble 5 or more
    times of 9 (binomial(9, 1/9): 0.15 %, under the interval's 2.5 %), so the median's interval stays in [1, 8]
    while the mean's reaches far below 0."""
    b = np.array([1.0] * 8 + [101.0])
    a = np.array([2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 1.0])
    d = M.paired_difference(a, b, draws=4000)
    assert d["mean"] == pytest.approx((36.0 - 100.0) / 9) and d["median"] == pytest.approx(4.0)
    lo, hi = d["median_ci95"]
    assert 1.0 <= lo <= 4.0 <= hi <= 8.0
    assert d["ci95"][0] < -15.0  # the mean's interval reaches the stumble
