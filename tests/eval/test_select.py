"""Checkpoint selection on validation episodes (eval/select.py) and the test / validation split (eval/scenario.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dls_quadruped.cli import UserError
from dls_quadruped.eval import select
from dls_quadruped.eval.__main__ import parse_args as eval_args
from dls_quadruped.eval.scenario import VALIDATION_SEED_OFFSET, split_seed
from dls_quadruped.eval.velocity_tracking import simple_commands


def test_split_seeds_are_disjoint_and_test_is_the_plain_seed():
    assert split_seed(0, "test") == 0 and split_seed(3, "test") == 3
    assert split_seed(3, "validation") == 3 + VALIDATION_SEED_OFFSET
    # the validation seeds of every report seed lie above every test seed
    assert min(split_seed(s, "validation") for s in range(100)) > max(split_seed(s, "test") for s in range(100))
    with pytest.raises(ValueError, match=r"unknown episode split 'train'; allowed: \['test', 'validation'\]"):
        split_seed(0, "train")
    with pytest.raises(ValueError, match="test and validation episodes stay disjoint"):
        split_seed(VALIDATION_SEED_OFFSET, "validation")


def test_validation_commands_differ_from_the_test_commands():
    test, val = simple_commands(64, split_seed(0, "test")), simple_commands(64, split_seed(0, "validation"))
    assert test.shape == val.shape
    # no validation command equals a test command (continuous draws)
    dist = np.abs(test[:, None, :] - val[None, :, :]).sum(-1)
    assert dist.min() > 1e-6


def test_eval_cli_split_sets_the_episode_seed(tmp_path):
    assert eval_args(["--policy", "p.pt"]).episode_seed == 0
    assert eval_args(["--policy", "p.pt", "--seed", "2", "--split",
                      "validation"]).episode_seed == 2 + VALIDATION_SEED_OFFSET
    with pytest.raises(SystemExit):
        eval_args(["--policy", "p.pt", "--split", "holdout"])


def test_candidates_every_k_and_the_newest(tmp_path):
    for it in (0, 25, 50, 75, 100, 120):  # train saves model_<k * save_interval>.pt and the last iteration's
        (tmp_path / f"model_{it}.pt").write_bytes(b"")
    (tmp_path / "model_best.pt").write_bytes(b"")  # not a numbered checkpoint: ignored
    found = select.run_checkpoints(tmp_path)
    assert list(found) == [0, 25, 50, 75, 100, 120]
    assert list(select.candidates(found, 50)) == [50, 100, 120]
    assert list(select.candidates(found, 25)) == [25, 50, 75, 100, 120]
    assert list(select.candidates(found, None)) == [0, 25, 50, 75, 100, 120]
    assert select.candidates({}, 50) == {}


def test_choose_highest_then_earliest_and_skips_nan():
    assert select.choose({49: 1.0, 99: 2.5, 149: 2.0}) == 99
    assert select.choose({49: 2.5, 99: 2.5}) == 49
    assert select.choose({49: float("nan"), 99: 0.1}) == 99
    with pytest.raises(UserError, match="no checkpoint has a finite validation score"):
        select.choose({49: float("nan")})


def test_metric_value_is_the_mean_over_episodes():
    res = {"scenario": "simple", "per_episode": {"reward": [1.0, 2.0, None, 4.0], "fell": [0, 1, 0, 0]}}
    assert select.metric_value(res, "reward") == pytest.approx(7.0 / 3.0)  # the null episode left out
    assert select.metric_value(res, "survived") == pytest.approx(0.75)
    with pytest.raises(UserError, match=r"records no per-episode 'cot'; choose --metric from those it records: "
                                        r"\['survived', 'reward'\]"):
        select.metric_value(res, "cot")


def test_select_uses_cached_validation_results_and_writes_the_choice(tmp_path, monkeypatch):
    run = tmp_path / "run"
    out = run / "selection" / "simple"
    out.mkdir(parents=True)
    seed = split_seed(0, "validation")
    for it, reward in ((50, 1.5), (100, 2.25), (120, 2.0)):
        (run / f"model_{it}.pt").write_bytes(b"")
        (out / f"model_{it}.json").write_text(json.dumps(
            {"scenario": "simple", "seed": seed, "episodes": 8,
             "per_episode": {"reward": [reward] * 8, "fell": [0] * 8}}))

    def no_eval(*args, **kwargs):
        raise AssertionError("a cached validation result was evaluated again")

    monkeypatch.setitem(select.SCENARIOS, "simple", _with_evaluate(select.SCENARIOS["simple"], no_eval))
    summary = select.main([str(run), "--every", "50", "--episodes", "8"])
    assert summary["chosen"]["iteration"] == 100 and summary["chosen"]["value"] == pytest.approx(2.25)
    assert summary["validation_seed"] == seed and summary["split"] == "validation"
    assert json.loads((out / "selection.json").read_text())["chosen"]["checkpoint"].endswith("model_100.pt")


def _with_evaluate(scenario, evaluate):
    import dataclasses

    return dataclasses.replace(scenario, evaluate=evaluate)


def test_select_bad_input_is_one_line(tmp_path):
    with pytest.raises(UserError, match="run directory .* not found"):
        select.main([str(tmp_path / "nope")])
    with pytest.raises(UserError, match="holds no model_<it>.pt checkpoint"):
        select.main([str(tmp_path)])
