"""The 7.1 experiment scripts (Figs. 17-23) end to end on a tiny scale: policies found by task
name, missing ones skipped with a note, tables and figures written, finished results reused."""

from __future__ import annotations

import csv
import json

import pytest
import torch

from dls_quadruped.eval import cot, gait, omni, speed, stairs, survival
from experiments import (
    fig17_simple_task,
    fig18_survival,
    fig18b_survival_sweep,
    fig19_stairs,
    fig20_speed,
    fig21_omni,
    fig22_cot,
    fig23_gait,
    rl_common,
)

SCRIPTS = {fig17_simple_task: "simple", fig18_survival: "survival", fig18b_survival_sweep: "survival_sweep",
           fig19_stairs: "stairs", fig20_speed: "speed",
           fig21_omni: "omni", fig22_cot: "cot", fig23_gait: "gait"}


class _Zero(torch.nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.zeros(x.shape[0], 28)


@pytest.fixture
def tiny(tmp_path, monkeypatch, save_policy):
    """Only a (zero-action) base policy; 2 episodes of 0.4 s per condition, two conditions per sweep."""
    policies = tmp_path / "policies"
    policies.mkdir()
    save_policy(_Zero(), 259, policies / "base_actor.pt")
    monkeypatch.setitem(rl_common.SCALES, "small", {"episodes": {s: 2 for s in SCRIPTS.values()},
                                                     "episode_length_s": 0.4})
    for module in (speed, cot, gait):
        monkeypatch.setattr(module, "SPEEDS", (0.5, 1.0))
    monkeypatch.setattr(stairs, "HEIGHTS", (0.05, 0.1))
    monkeypatch.setattr(omni, "DIRECTIONS_DEG", (0, 180))
    monkeypatch.setattr(omni, "MAGNITUDES", (0.5, 1.0))
    monkeypatch.setattr(survival, "ROWS", 2)
    monkeypatch.setattr(survival, "SWEEP_ROWS", 2)
    return tmp_path


def run(module, tmp_path, name):
    out = tmp_path / name
    module.main(["--scale", "small", "--out", str(out), "--policy-dir", str(tmp_path / "policies"),
                 "--num-workers", "0"])
    return out


def read_csv(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("module", list(SCRIPTS), ids=lambda m: m.__name__.split(".")[-1])
def test_script_writes_base_and_skips_missing_policies(module, tiny, capsys):
    scenario = SCRIPTS[module]
    out = run(module, tiny, scenario)
    printed = capsys.readouterr().out
    for task in ("rough", "speed", "climb"):
        assert f"{task}_actor.pt not found" in printed
    cfg = json.loads((out / "config.json").read_text())
    assert set(cfg["skipped"]) == {"rough", "speed", "climb"} and list(cfg["policies"]) == ["base"]
    assert cfg["scenario"] == scenario and cfg["episodes_per_condition"] == 2
    rows = read_csv(out / "table.csv")
    assert rows and {r["policy"] for r in rows} == {"base"}
    per_policy = json.loads((out / "base" / f"{scenario}.json").read_text())
    assert per_policy["scenario"] == scenario and per_policy["episode_steps"] == 20
    assert (out / "base" / f"{scenario}.png").stat().st_size > 0
    figures = [p for p in out.glob("fig*.png")]
    assert len(figures) == 1 and figures[0].stat().st_size > 0
    results = json.loads((out / "results.json").read_text())
    assert "per_episode" not in results["results"]["base"]


def test_finished_results_are_reused_until_the_policy_changes(tiny, capsys, save_policy):
    out = run(fig20_speed, tiny, "speed")
    first = (out / "base" / "speed.json").read_text()
    run(fig20_speed, tiny, "speed")
    assert "up to date, not evaluated again" in capsys.readouterr().out
    assert (out / "base" / "speed.json").read_text() == first
    save_policy(torch.nn.Sequential(torch.nn.Linear(259, 28)), 259, tiny / "policies" / "base_actor.pt")
    run(fig20_speed, tiny, "speed")
    assert "not evaluated again" not in capsys.readouterr().out
    assert json.loads((out / "base" / "speed.json").read_text())["experiment_key"]["sha256"] != \
        json.loads(first)["experiment_key"]["sha256"]


def test_no_policy_at_all_still_writes_the_notes(tmp_path, capsys):
    (tmp_path / "policies").mkdir()
    out = run(fig17_simple_task, tmp_path, "empty")
    assert json.loads((out / "config.json").read_text())["policies"] == {}
    assert not list(out.glob("fig*.png")) and "base_actor.pt not found" in capsys.readouterr().out


def test_recipe_variant_takes_the_retrained_experts(tiny, capsys, save_policy):
    """``--variant recipe`` evaluates ``<task>_recipe_actor.pt2`` and records it; the thesis files are not used."""
    save_policy(_Zero(), 259, tiny / "policies" / "base_recipe_actor.pt2")
    out = tiny / "recipe"
    fig17_simple_task.main(["--scale", "small", "--out", str(out), "--policy-dir", str(tiny / "policies"),
                            "--num-workers", "0", "--variant", "recipe"])
    assert "rough_recipe_actor.pt2 not found" in capsys.readouterr().out
    cfg = json.loads((out / "config.json").read_text())
    assert list(cfg["policies"]) == ["base"] and cfg["policies"]["base"]["path"].endswith("base_recipe_actor.pt2")


def test_every_committed_variant_file_exists():
    """The experiments' file names of each variant (rl_common.VARIANTS) match what docs/policies holds."""
    policies = rl_common.Policies(rl_common.POLICY_DIR, "thesis")
    for task in rl_common.TASKS:
        assert policies.expert(task).is_file(), policies.expert(task)
    recipe = rl_common.Policies(rl_common.POLICY_DIR, "recipe")
    for task in rl_common.TASKS:
        assert recipe.expert(task).is_file(), recipe.expert(task)
    for task in ("base", "rough", "speed"):
        assert policies.student(task).is_file(), policies.student(task)
    for task in ("base", "speed"):
        assert recipe.student(task).is_file(), recipe.student(task)


def test_walking_height_of_a_standing_policy(tmp_path, save_policy):
    """experiments/walking_height.py on a zero-action policy (the controller holds the robot near its nominal
    stance): the CoM height is the base's height plus the CoM offset, within a few cm of the MPC's default."""
    from experiments import walking_height

    save_policy(_Zero(), 259, tmp_path / "base_recipe_actor.pt2")
    out = walking_height.main(["--policy-dir", str(tmp_path), "--tasks", "base", "speed", "--robots", "2",
                               "--seconds", "0.4", "--settle", "0.2", "--out", str(tmp_path / "out")])
    base = out["experts"]["base"]
    assert "speed" not in out["experts"] and base["robots_standing"] == 2
    assert abs(base["com_height_m"] - out["mpc_default_com_height_m"]) < 0.08
    assert out["validation_seed"] == 1_000_003
    assert json.loads((tmp_path / "out" / "walking_height.json").read_text())["experts"]["base"] == base
    with pytest.raises(SystemExit):
        walking_height.main(["--seconds", "1", "--settle", "1"])
    # --policy NAME=FILE: that file under that name, the same episodes, so the same height as above
    named = walking_height.main(["--policy", f"zero={tmp_path / 'base_recipe_actor.pt2'}", "--robots", "2",
                                 "--seconds", "0.4", "--settle", "0.2", "--out", str(tmp_path / "out2")])
    assert list(named["experts"]) == ["zero"] and named["experts"]["zero"]["com_height_m"] == base["com_height_m"]
    for bad in (["--policy", "nofile"], ["--policy", f"x={tmp_path / 'missing.pt2'}"]):
        with pytest.raises(SystemExit):
            walking_height.main(bad)


def test_walking_height_help_and_a_bad_variant():
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "experiments.walking_height"]
    ok = subprocess.run([*cmd, "--help"], cwd=rl_common.REPO, capture_output=True, text=True, timeout=120, check=False)
    assert ok.returncode == 0 and "--com-height" in ok.stdout and "validation" in ok.stdout
    bad = subprocess.run([*cmd, "--variant", "bogus"], cwd=rl_common.REPO, capture_output=True, text=True,
                         timeout=120, check=False)
    assert bad.returncode == 2 and "invalid choice: 'bogus'" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_fig17_keeps_per_episode_files_that_give_its_paired_row_and_the_commit(tiny, save_policy, monkeypatch):
    """The verdict row of Fig. 17 (speed - base, reward per step) can be recomputed from the per-expert files the
    script writes, and every file says which commit it ran on."""
    from dls_quadruped.eval.provenance import provenance
    from experiments import verdict_intervals

    torch.manual_seed(0)
    save_policy(torch.nn.Sequential(torch.nn.Linear(259, 28), torch.nn.Tanh()), 259,
                tiny / "policies" / "speed_actor.pt")
    out = run(fig17_simple_task, tiny, "fig17")
    monkeypatch.setattr(verdict_intervals, "RESULTS", tiny)
    verdict_intervals._json.cache_clear()
    verdict_intervals._csv.cache_clear()
    try:
        from_files = verdict_intervals.expert_gap("fig17", "simple", "speed", "base", "reward")
        printed = verdict_intervals.paired_csv("fig17", "speed - base", "mean reward per step")
    finally:
        verdict_intervals._json.cache_clear()
        verdict_intervals._csv.cache_clear()
    assert from_files.value != 0.0  # two different policies
    assert (from_files.value, from_files.lo, from_files.hi) == pytest.approx(
        (printed.value, printed.lo, printed.hi), abs=5e-5)
    head = provenance()
    for f in (out / "base" / "simple.json", out / "speed" / "simple.json", out / "config.json", out / "results.json"):
        rec = json.loads(f.read_text())
        assert rec["git_commit"] == head["git_commit"] and rec["git_dirty"] == head["git_dirty"], f
