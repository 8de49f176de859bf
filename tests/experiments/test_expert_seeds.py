"""The expert-seeds analysis (experiments/expert_seeds.py) on evaluation files written by hand: pooled contrasts are
the mean of the per-seed ones, the drop's path at seed 0 adds up exactly, the plan's labels and recipe rule hold on
hand-made intervals, and Fig. 17's per-seed rows refuse episodes that are not Fig. 17's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dls_quadruped.cli import UserError
from experiments import expert_seeds as X

E_SIMPLE, E_SWEEP = 40, 30


def _simple(reward: np.ndarray, commands: list | None = None) -> dict:
    n = reward.size
    axes = {a: {"slope": 0.9} for a in ("v_x", "v_y", "omega_z")}
    return {"per_episode": {"reward": reward.tolist(), "fell": [False] * n,
                            "command": commands or [[0.5, 0.0, 0.1 * i] for i in range(n)]}, "axes": axes}


def _sweep(fell: np.ndarray) -> dict:
    return {"per_episode": {"fell": fell.astype(bool).tolist()}}


def _write(out: Path, name: str, set_name: str, res: dict) -> None:
    scenario = X.SETS[set_name][0]
    (out / name / set_name).mkdir(parents=True, exist_ok=True)
    (out / name / set_name / f"{scenario}.json").write_text(json.dumps(res))


def _experiment(out: Path, reward_of: dict[str, float], fall_every: dict[str, int]) -> None:
    """Every policy of the plan: a shared episode baseline plus the policy's offset; policy p falls on every
    ``fall_every[p]``-th sweep episode."""
    rng = np.random.default_rng(1)
    base = rng.normal(2.2, 0.05, size=E_SIMPLE)
    for name in X.policy_names():
        fell = np.zeros(E_SWEEP)
        fell[::fall_every[name]] = 1
        for set_name in X.sets_of(name):
            if set_name.endswith("simple"):
                _write(out, name, set_name, _simple(base + reward_of[name]))
            else:
                _write(out, name, set_name, _sweep(fell))


OFFSETS = {"D0_sel": 0.10, "D1_sel": 0.12, "D2_sel": 0.08, "D0_450": 0.05, "D1_450": 0.06, "D2_450": 0.04,
           "T0_450": 0.01, "T1_450": 0.0, "T2_450": 0.02, "base_actor": 0.0}
FALLS = {"D0_sel": 2, "D1_sel": 2, "D2_sel": 2, "D0_450": 3, "D1_450": 3, "D2_450": 3,
         "T0_450": 5, "T1_450": 5, "T2_450": 5, "base_actor": 5}


def test_pooled_contrasts_are_the_mean_of_the_seeds_and_the_drop_adds_up(tmp_path: Path) -> None:
    _experiment(tmp_path, OFFSETS, FALLS)
    rows = {(r["contrast"], r["outcome"]): r for r in X.contrasts(X.load(tmp_path))}
    reward = "reward per step"
    budget = np.mean([OFFSETS[f"D{s}_sel"] - OFFSETS[f"D{s}_450"] for s in X.SEEDS])
    assert rows[("budget: chosen - 450, pooled", reward)]["mean"] == pytest.approx(budget)
    recipe = np.mean([OFFSETS[f"D{s}_450"] - OFFSETS[f"T{s}_450"] for s in X.SEEDS])
    assert rows[("recipe: default - Table 6 at 450, pooled", reward)]["mean"] == pytest.approx(recipe)
    # survival: falls on every 2nd (chosen), 3rd (450) and 5th (Table 6) of 30 episodes: 15, 10, 6 falls
    survival = "survival (sweep)"
    assert rows[("budget, seed 1", survival)]["mean"] == pytest.approx((10 - 15) / 30)
    assert rows[("recipe, seed 2", survival)]["mean"] == pytest.approx((6 - 10) / 30)
    for outcome in (reward, survival):  # telescoping: drop = code + recipe at seed 0 + budget at seed 0
        parts = sum(rows[(c, outcome)]["mean"] for c in
                    ("code: T0 at 450 (today) - base_actor.pt", "recipe, seed 0", "budget, seed 0"))
        assert rows[("the drop: base_recipe_actor.pt2 - base_actor.pt", outcome)]["mean"] == pytest.approx(parts)
    # identical sweep episodes everywhere (falls on the same episodes): the spread between the seeds is 0 exactly
    spread = rows[("seed spread: D1 - D0, chosen", survival)]
    assert spread["mean"] == 0 and spread["ci95"] == [0.0, 0.0] and spread["label"] == "within +-0.1"
    summary = X.report(tmp_path, fig17=tmp_path / "no_fig17")
    assert (tmp_path / "table.md").read_text().count("| budget, seed 0 |") == 2
    # validation: the default earns more (> 0) but falls on 4 more of 30 episodes (inconclusive beyond 5 points)
    assert summary["recipe_choice"]["reward"]["label"] == "> 0"
    assert summary["recipe_choice"]["decision"].startswith("the default stays; trade-off")
    assert summary["fig17"] == []


def test_labels_follow_the_margin() -> None:
    assert X.label([0.01, 0.03], 0.02) == "> 0"
    assert X.label([-0.03, -0.001], 0.02) == "< 0"
    assert X.label([-0.015, 0.019], 0.02) == "within +-0.02"
    assert X.label([-0.025, 0.01], 0.02) == "inconclusive"
    assert X.label([float("nan"), 0.0], 0.02) == "-"


def test_recipe_rule() -> None:
    def rule(reward: list[float], survival: list[float]) -> str:
        return X.decide({"reward": (reward, 0.02), "survived": (survival, 0.05)})

    assert rule([-0.01, 0.03], [-0.04, 0.02]).startswith("the default stays: not worse")
    # Table 6 better on survival, the default not better on reward: switch
    assert rule([-0.01, 0.01], [-0.20, -0.08]).startswith("Table 6 becomes the default: better on survived")
    # Table 6 better on survival, the default better on reward: a trade-off, the default stays
    assert rule([0.03, 0.05], [-0.20, -0.08]).startswith("the default stays; trade-off")
    # worse beyond the margin but not below 0: inconclusive, the default stays
    assert rule([-0.03, 0.01], [-0.04, 0.02]).startswith("the default stays; trade-off")


def test_fig17_rows_pair_each_seed_with_the_committed_experts(tmp_path: Path) -> None:
    commands = [[0.4, 0.0, 0.01 * i] for i in range(E_SIMPLE)]
    base = np.full(E_SIMPLE, 2.0)
    res = {f"D{s}_sel": {"test_simple": _simple(base + 0.1 * s, commands)} for s in X.SEEDS}
    for task, r in (("rough", 1.9), ("speed", 1.5), ("climb", 2.1)):
        (tmp_path / task).mkdir()
        (tmp_path / task / "simple.json").write_text(json.dumps(_simple(np.full(E_SIMPLE, r), commands)))
    rows = {(r["seed"], r["versus"]): r for r in X.fig17_rows(res, tmp_path)}
    assert rows[(0, "rough")]["relative"] == pytest.approx(2.0 / 1.9 - 1)
    assert rows[(0, "rough")]["holds"]  # above, by 5.3 % < 20 %
    assert not rows[(2, "speed")]["holds"]  # 2.2 / 1.5 - 1 = 47 %: above the thesis's 20 %
    assert not rows[(0, "climb")]["holds"]  # below climb
    (tmp_path / "rough" / "simple.json").write_text(json.dumps(_simple(np.full(E_SIMPLE, 1.9))))
    with pytest.raises(UserError, match="not Fig. 17's episodes"):
        X.fig17_rows(res, tmp_path)


def test_policy_files(tmp_path: Path) -> None:
    assert X.policy_file("D0_sel", tmp_path, tmp_path).name == "base_recipe_actor.pt2"
    assert X.policy_file("D0_450", tmp_path, tmp_path) == tmp_path / "base_recipe_s0_450" / "model_450.pt"
    assert X.policy_file("T2_450", tmp_path, tmp_path) == tmp_path / "base_thesis_s2" / "model_449.pt"
    with pytest.raises(UserError, match="no checkpoint chosen yet"):
        X.policy_file("D1_sel", tmp_path, tmp_path)
    sel = X.selection_dir(tmp_path, 1)
    sel.mkdir(parents=True)
    (sel / "selection.json").write_text(json.dumps({"chosen": {"checkpoint": "/elsewhere/model_800.pt"}}))
    assert X.policy_file("D1_sel", tmp_path / "runs", tmp_path) == tmp_path / "runs" / "base_recipe_s1" / "model_800.pt"
    with pytest.raises(UserError, match="not finished its 1 000 iterations"):
        X.select(tmp_path / "runs", tmp_path, 1, 0)


def test_help_and_a_bad_command():
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "experiments.expert_seeds"]
    ok = subprocess.run([*cmd, "--help"], cwd=X.REPO, capture_output=True, text=True, timeout=120, check=False)
    assert ok.returncode == 0 and "--runs" in ok.stdout and "--only" in ok.stdout
    bad = subprocess.run([*cmd, "bogus"], cwd=X.REPO, capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "invalid choice: 'bogus'" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
