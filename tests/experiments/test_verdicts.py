"""The verdict rules of ``docs/experiments.md`` on hand-made intervals, and the page's verdict table against the
committed result files (``experiments/verdicts.py``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from experiments.verdict_intervals import Interval, apart, parse, verdict
from experiments.verdicts import ROWS, Row, documented, render

REPO = Path(__file__).resolve().parents[2]


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
    must follow (``python -m experiments.verdicts`` prints the new table)."""
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
    from experiments.verdict_intervals import gap, relative_gap_difference

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
    from experiments.verdict_intervals import relative_gap_difference

    folder, naive = "table16_seeds_medium", ("naive_warm_start_M4000", "naive_warm_start_M10000")
    rl = ("rl_warm_start_M4000", "rl_warm_start_M10000")
    joint = relative_gap_difference(folder, naive, rl, paired_seeds=(False, True))
    apart = relative_gap_difference(folder, naive, rl)
    assert joint.value == pytest.approx(apart.value)
    assert apart.lo < joint.lo < joint.value < joint.hi < apart.hi


def test_an_exploratory_row_carries_no_verdict_and_a_note_may_be_computed():
    row = Row("x", "claim", "t", "label", lambda: iv(0.1, 0.2), "p.md", +1, exploratory="designed after looking",
              note=lambda: "computed")
    assert row.word(row.ours()) == "exploratory"
    assert row.verdict_text(row.ours()) == "**exploratory**: designed after looking; no verdict (rule 5); computed"


def test_a_computed_reason_counts_only_when_it_says_something():
    """``why`` computed (e.g. "expert seed 0 only" from the seeds' cells): "" leaves the rule's verdict."""
    for why, word in ((lambda: "", "reproduced"), (lambda: "expert seed 0 only: ...", "inconclusive")):
        row = Row("x", "claim", "t", "label", lambda: iv(0.1, 0.2), "p.md", +1, why=why)
        assert row.word(row.ours()) == word
        assert row.verdict_text(row.ours()).startswith(f"**{word}**")


def test_table14_rows_are_checked_across_the_expert_seeds():
    """The seeds' own intervals decide: the initial-cost row holds with all three, the two reward rows do not."""
    from experiments.verdict_intervals import expert_seeds_note, expert_seeds_why
    from experiments.verdicts import _T14_IC, _T14_RA, _T14_RN, T14, T14X

    for seed0 in (T14, T14X):  # expert seed 0 judged on the medium run and on the 100-episode one
        assert expert_seeds_why(seed0, *_T14_IC) == "" and expert_seeds_note(seed0, *_T14_IC).startswith("holds across")
        for row in (_T14_RN, _T14_RA):
            assert expert_seeds_why(seed0, *row).startswith("expert seed 0 only")
            assert expert_seeds_note(seed0, *row) == ""


def test_table14_rows_at_each_seeds_own_height_read_the_height_cells():
    """The plan amendment's cells (every reference at the seed's walking height) are another run than part 2's:
    each seed's text is the interval of its ``_height`` folder, not of the default-height one, with its verdict."""
    from experiments.verdict_intervals import EXPERT_SEED_TABLE14, expert_seeds_at_height, gap, verdict
    from experiments.verdicts import _T14_IC, _T14_RA, _T14_RN

    for row in (_T14_IC, _T14_RN, _T14_RA):
        a, b, key, direction, digits = row
        text = expert_seeds_at_height(*row)
        for name, folder in EXPERT_SEED_TABLE14.items():
            at, default = gap(folder + "_height", a, b, key, digits=digits), gap(folder, a, b, key, digits=digits)
            assert f"{name} {at.text} ({verdict(at, direction)})" in text
            assert at.text != default.text


def test_equivalence_needs_the_interval_inside_the_margin():
    from experiments.verdict_intervals import equivalence

    assert equivalence(iv(-1.5, 4.9), 5.0) == "equivalent"     # the sweep's plain / today / 400 000 cell
    assert equivalence(iv(-8.7, 4.8), 5.0) == "inconclusive"   # disturbed / today / 100 000: crosses -5
    assert equivalence(iv(-24.0, -3.9), 5.0) == "different"


def test_the_relative_reading_of_38_percent_scales_base_alones_survival():
    """The retrained pushes run: base alone 69 % (66 of 96), +38 % of it is +0.26; [+0.076, +0.271] holds it within
    the 0.10 survival margin, while 0.38 +- 0.10 (the absolute reading) is missed."""
    from experiments.verdict_intervals import pushes_reading

    assert "69 % is +0.26 ± 0.10, reproduced on that reading" in pushes_reading("retrained/pushes_recipe")
    assert verdict(iv(0.076, 0.271), +1, 0.38, 0.10) == "contradicted"
    assert verdict(iv(0.076, 0.271), +1, 0.38 * 66 / 96, 0.10) == "reproduced"


@pytest.fixture
def pages(tmp_path, monkeypatch):
    """A copy of docs/experiments/ and docs/experts.md that the prose check reads instead of the real ones."""
    import shutil

    from experiments import verdict_prose

    docs = tmp_path / "docs"
    shutil.copytree(REPO / "docs" / "experiments", docs / "experiments",
                    ignore=lambda d, names: [n for n in names if (Path(d) / n).is_dir()])
    for name in ("experiments.md", "experts.md"):
        shutil.copy(REPO / "docs" / name, docs / name)
    monkeypatch.setattr(verdict_prose, "DOCS", docs)
    monkeypatch.setattr(verdict_prose, "PAGES", [docs / "experiments.md", *sorted((docs / "experiments").glob("*.md")),
                                                 docs / "experts.md"])
    return docs


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text
    path.write_text(text.replace(old, new), encoding="utf-8")


def test_the_section_pages_state_every_rows_verdict_as_the_table():
    from experiments.verdict_prose import PROSE, overclaims, row_mismatches

    assert {r.claim for r in ROWS} == set(PROSE)
    assert row_mismatches(ROWS) == []
    assert overclaims() == []


def test_a_page_that_states_another_label_fails_the_check(pages, capsys):
    """The Fig. 18 row is inconclusive; a page that calls it reproduced, or that no longer states it, fails
    ``verdicts.py --check`` while the table itself still matches."""
    from experiments.verdict_prose import row_mismatches
    from experiments.verdicts import main

    page = pages / "experiments" / "experts.md"
    edit(page, '"Climb is best, even above rough": inconclusive.', '"Climb is best, even above rough": reproduced.')
    (bad,) = row_mismatches(ROWS)
    assert bad.startswith("2 · Fig. 18 ") and "says 'reproduced', the table 'inconclusive'" in bad
    assert main(["--check"]) == 1
    assert "disagree with the table" in capsys.readouterr().out
    edit(page, '"Climb is best, even above rough": reproduced.', "Climb and rough cannot be ranked here.")
    (bad,) = row_mismatches(ROWS)
    assert "states no verdict" in bad


def test_the_rule_alone_and_another_reading_are_not_the_verdict():
    from experiments.verdict_prose import stated

    phrase = ('"The MPC raises base\'s survival"',)
    assert stated('- **"The MPC raises base\'s survival": inconclusive** (rule alone: contradicted)', phrase) == \
        ["inconclusive"]
    assert stated('- **"The MPC raises base\'s survival"** (rule alone: contradicted), 0.26 reproduced on that '
                  'reading', phrase) == []
    assert stated('- **"The MPC raises base\'s survival"**: one line\n  and the next: **not reproduced**', phrase) == \
        ["not reproduced"]
    assert stated("- another bullet: reproduced", phrase) == []


@pytest.mark.parametrize(("sentence", "flagged"), [
    ("At 100 000 datapoints the gap is gone.", True),
    ("At 400 000 there is no gap in any cell.", True),
    ("The two encodings are equivalent.", True),
    ("Speed's training converges.", True),
    ("The gap is gone within the plan's ±5-point margin.", False),
    ("That the gap is gone is not shown.", False),
    ("Speed's return had not converged at iteration 999.", False),
    ("Fig. 18 shows the two experts are equivalent within a 10-point margin.", False),
])
def test_an_absence_or_convergence_needs_a_margin_or_a_negation(tmp_path, sentence, flagged):
    from experiments.verdict_prose import overclaims

    page = tmp_path / "p.md"
    page.write_text(f"# A page\n\nA first sentence. {sentence} A last sentence.\n", encoding="utf-8")
    assert bool(overclaims([page])) == flagged


def _repo(tmp_path: Path) -> Path:
    import subprocess

    repo = tmp_path / "repo"
    (repo / "docs" / "experiments").mkdir(parents=True)
    for args in (["init", "-q"], ["config", "user.email", "t@t"], ["config", "user.name", "t"]):
        subprocess.run(["git", "-C", str(repo), *args], check=True)
    return repo


def _commit(repo: Path, message: str) -> str:
    import subprocess

    subprocess.run(["git", "-C", str(repo), "add", "-A"], check=True)
    subprocess.run(["git", "-C", str(repo), "commit", "-q", "-m", message], check=True)
    return subprocess.run(["git", "-C", str(repo), "rev-parse", "--short=7", "HEAD"], check=True,
                          capture_output=True, text=True).stdout.strip()


def test_a_plan_header_must_name_the_commit_that_added_it(tmp_path):
    from experiments.verdict_prose import plan_errors

    repo = _repo(tmp_path)
    plan = repo / "docs" / "experiments" / "x_plan.md"
    plan.write_text("# Plan: x (written 2026-11-27 19:45 UTC)\n\nbody\n")
    first = _commit(repo, "plan")
    (repo / "docs" / "experiments" / "other.md").write_text("# other\n")
    second = _commit(repo, "other")
    assert any("hand-written time" in e for e in plan_errors(repo))
    plan.write_text(f"# Plan: x (committed at {second})\n\nbody\n")  # a commit that did not add it
    assert any("did not add that heading" in e for e in plan_errors(repo))
    plan.write_text("# Plan: x (committed at 0123456)\n\nbody\n")
    assert any("not a commit" in e for e in plan_errors(repo))
    plan.write_text(f"# Plan: x (committed at {first})\n\nbody\n\n## Amendment (committed at {first})\n")
    assert any("## Amendment" in e and "did not add" in e for e in plan_errors(repo))
    plan.write_text(f"# Plan: x (committed at {first})\n\nbody\n")
    assert plan_errors(repo) == []


def test_the_committed_plan_headers_name_their_commits():
    import subprocess

    from experiments.verdict_prose import plan_errors

    try:
        errors = plan_errors()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("no git history in this copy of the tree")
    assert errors == []


def test_floor_reason_quotes_the_table_it_reads(tmp_path, monkeypatch):
    """``floor_why`` prints the survival cells of the named rows, without their counts, from the result table."""
    from experiments import verdict_intervals

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "t.csv").write_text('Warm start,survival\n"base alone","4 % [1, 10] (n=100)"\n'
                                            '"base warm (2 students)","7 % [3, 14] (n=100x2)"\n')
    monkeypatch.setattr(verdict_intervals, "RESULTS", tmp_path)
    assert verdict_intervals.floor_why("run", "t.csv", "base alone", "base warm (2 students)") == (
        "base alone survives 4 % [1, 10], the warm start 7 % [3, 14]: the task's floor, no room to rise")
