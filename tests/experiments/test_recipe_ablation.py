"""experiments/recipe_ablation.py's report: runs compared at one budget, variants paired against the baseline."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from experiments.recipe_ablation import _validation, end_episodes, main, paired_against


def _write(run: Path, it: int, per_episode: list[float]) -> None:
    d = run / "selection" / "simple"
    d.mkdir(parents=True, exist_ok=True)
    res = {"reward": {"per_step": float(np.mean(per_episode))}, "per_episode": {"reward": per_episode}}
    (d / f"model_{it}.json").write_text(json.dumps(res))


def test_end_of_budget_is_the_newest_checkpoint_at_or_before_it(tmp_path):
    run = tmp_path / "ent0_std05_s0"
    for it, v in ((50, 1.0), (150, 2.0), (200, 3.0), (499, 4.0)):
        _write(run, it, [v, v])
    assert _validation(run, 199) == {50: 1.0, 150: 2.0}
    assert list(_validation(run)) == [50, 150, 200, 499]
    it, ep = end_episodes(run, 200)
    assert it == 200 and ep.tolist() == [3.0, 3.0]
    assert end_episodes(run, 10) is None


def test_paired_against_the_baseline_by_hand():
    # Every episode of the variant is 0.5 above the baseline's in both seeds: the difference is 0.5 exactly, with an
    # interval of zero width whatever is resampled. Seed 1's runs differ by 0.25 on episode 0 and 0.75 on episode 1:
    # its own difference is their mean, 0.5, and both seeds together: the mean over episodes of the seed means.
    base = {0: np.array([1.0, 2.0]), 1: np.array([1.0, 2.0])}
    var = {0: np.array([1.5, 2.5]), 1: np.array([1.25, 2.75])}
    (d,) = paired_against({"ent0": base, "x": var}, "ent0")
    assert d["variant"] == "x" and d["seeds"] == [0, 1]
    assert d["per_seed"][0]["mean"] == 0.5 and d["per_seed"][0]["ci95"] == [0.5, 0.5]
    assert d["per_seed"][1]["mean"] == 0.5
    assert abs(d["mean"] - 0.5) < 1e-12
    assert d["ci95"][0] <= 0.5 <= d["ci95"][1]
    assert paired_against({"x": var}, "ent0") == []  # no baseline evaluated yet: nothing to pair


@pytest.mark.parametrize("argv, message", [
    (["report", "--baseline", "nope"], "unknown variant 'nope'; allowed: ["),
    (["report", "--iterations", "0"], "--iterations: must be >= 1"),
])
def test_bad_report_arguments_are_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_help_names_every_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "{run,eval,report}" in out and "--baseline" in out


def test_a_bad_flag_is_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["report", "--no-such-flag"])
    assert e.value.code == 2
    assert "unrecognized arguments: --no-such-flag" in capsys.readouterr().err
