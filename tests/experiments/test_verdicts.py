"""The verdict rules of ``docs/experiments.md`` on hand-made intervals, and the page's verdict table against the
committed result files (``experiments/verdicts.py``)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from experiments.verdicts import (
    ROWS,
    Interval,
    Row,
    apart,
    documented,
    parse,
    render,
    verdict,
)


def iv(lo: float, hi: float) -> Interval:
    return Interval((lo + hi) / 2, lo, hi, f"[{lo}, {hi}]")


@pytest.mark.parametrize(("lo", "hi", "direction", "expected"), [
    (0.1, 0.5, +1, "reproduced"),      # excludes 0 in the thesis's direction
    (-0.5, -0.1, +1, "contradicted"),  # excludes 0 the other way
    (-0.1, 0.3, +1, "inconclusive"),   # contains 0
    (-0.5, -0.1, -1, "reproduced"),
    (0.1, 0.5, -1, "contradicted"),
    (0.0, 0.4, +1, "inconclusive"),    # touching 0 does not exclude it
])
def test_a_difference_is_judged_by_the_side_of_zero(lo, hi, direction, expected):
    assert verdict(iv(lo, hi), direction) == expected


def test_a_stated_size_can_contradict_an_interval_that_contains_zero():
    # Table 11's shape: the thesis has naive 30 points below DAgger, ours is [-5, +3] with a 5-point margin
    assert verdict(iv(-5.0, 3.0), -1, thesis=-30.42, margin=5.0) == "contradicted"
    # the small scale's [-47.3, -7.3] holds the thesis's -30.42: the direction decides
    assert verdict(iv(-47.3, -7.3), -1, thesis=-30.42, margin=5.0) == "reproduced"
    # right direction but far too small: the size decides
    assert verdict(iv(-5.0, -1.0), -1, thesis=-30.42, margin=5.0) == "contradicted"
    # misses the value by less than the margin: undecided
    assert verdict(iv(-26.0, 3.0), -1, thesis=-30.42, margin=5.0) == "inconclusive"


@pytest.mark.parametrize(("lo", "hi", "expected"), [
    (1.56, 1.69, "contradicted"),   # Fig. 20: outside 2.0 +- 0.2
    (1.85, 2.10, "reproduced"),     # inside 2.0 +- 0.2
    (1.70, 1.90, "inconclusive"),   # straddles 1.8
])
def test_a_value_claim_needs_the_interval_inside_or_outside_the_margin(lo, hi, expected):
    assert verdict(iv(lo, hi), 0, thesis=2.0, margin=0.2) == expected


def test_no_interval_is_inconclusive_and_a_value_claim_without_margin_is_refused():
    assert verdict(None, +1) == "inconclusive"
    with pytest.raises(ValueError):
        verdict(iv(0.0, 1.0), 0, thesis=1.0)


def test_a_reason_overrides_the_rule_and_names_it():
    row = Row("x", "claim", "t", "label", lambda: iv(-5.0, 3.0), "p.md", -1, -30.42, 5.0, why="scales disagree")
    assert row.verdict_text(row.ours()) == "**inconclusive**: scales disagree (rule alone: contradicted)"
    plain = Row("x", "claim", "t", "label", lambda: iv(0.1, 0.2), "p.md", +1, note="a caveat")
    assert plain.verdict_text(plain.ours()) == "**reproduced**; a caveat"


def test_unpaired_intervals_count_only_when_apart():
    assert verdict(apart(iv(0.130, 0.160), iv(0.194, 0.233)), -1) == "reproduced"   # Table 11's MSEs
    assert verdict(apart(iv(0.187, 0.227), iv(0.194, 0.233)), -1) == "inconclusive"  # Fig. 24's, overlapping


def test_cells_are_parsed_as_the_files_print_them():
    assert parse("97.7 % [91.8, 100.1]") == Interval(97.7, 91.8, 100.1, "97.7 % [91.8, 100.1]")
    assert parse("0 % [0, 19] (n=16x3) (84.2 %)").hi == 19.0
    assert parse("-0.06 [-0.19, +0.00]").lo == -0.19


def test_the_documented_table_is_the_one_the_result_files_give():
    """docs/experiments.md's table is ``render()``: a result file that changes changes the verdicts, and the page
    must follow (``python experiments/verdicts.py`` prints the new table)."""
    assert documented() == render()


def test_every_row_links_a_section_that_exists():
    for row in ROWS:
        page, _, anchor = row.page.partition("#")
        text = (REPO / "docs" / "experiments" / page).read_text(encoding="utf-8")
        slugs = {re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
                 for line in text.splitlines() if line.startswith("#")}
        assert anchor in slugs, f"{row.ref}: {page} has no section #{anchor}"


def test_the_joint_bootstrap_of_two_relative_changes_centres_on_their_difference():
    """Table 16: naive's Δ minus the RL warm start's Δ at 4 000 samples, against the two Δ computed one by one."""
    from experiments.verdicts import gap, relative_gap_difference

    folder = "table16_samples_medium"
    naive = gap(folder, "naive_warm_start_M4000", "naive_warm_start_M10000", relative=True)
    rl = gap(folder, "rl_warm_start_M4000", "rl_warm_start_M10000", relative=True)
    both = relative_gap_difference(folder, ("naive_warm_start_M4000", "naive_warm_start_M10000"),
                                   ("rl_warm_start_M4000", "rl_warm_start_M10000"))
    assert both.value == pytest.approx(naive.value - rl.value)
    assert both.lo < both.value < both.hi
    assert both.hi - both.lo < (naive.hi - naive.lo) + (rl.hi - rl.lo)  # pairing narrows the interval


def test_students_paired_in_both_rl_rows_keep_the_value_and_narrow_the_interval():
    """Table 16 with three students: the RL rows at 4 000 and 10 000 samples hold the same students, so resampling
    them together (paired_seeds) leaves the point value as it is and narrows the interval."""
    from experiments.verdicts import relative_gap_difference

    folder, naive = "table16_seeds_medium", ("naive_warm_start_M4000", "naive_warm_start_M10000")
    rl = ("rl_warm_start_M4000", "rl_warm_start_M10000")
    joint = relative_gap_difference(folder, naive, rl, paired_seeds=(False, True))
    apart = relative_gap_difference(folder, naive, rl)
    assert joint.value == pytest.approx(apart.value)
    assert apart.lo < joint.lo < joint.value < joint.hi < apart.hi
