"""--set KEY=VALUE: parsed as YAML into one nested overrides dict, checked like the task file, and reaching the
config of train, eval and the closed loop (play's: tests/learning/test_play.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
import yaml

from dls_quadruped.cli import (
    ArgumentParser,
    add_set_argument,
    set_overrides,
    set_pair,
)
from dls_quadruped.closed_loop import __main__ as closed_loop
from dls_quadruped.closed_loop import episodes as closed_loop_episodes
from dls_quadruped.envs.config import TASKS_DIR, ConfigError, load_task, merge_overrides
from dls_quadruped.eval import __main__ as eval_main
from dls_quadruped.learning import train

REPO = Path(__file__).resolve().parents[1]
POLICY = REPO / "docs" / "policies" / "base_actor.pt"


@pytest.mark.parametrize(("text", "key", "value"), [
    ("agent.algorithm.entropy_coef=0.0", "agent.algorithm.entropy_coef", 0.0),
    ("env.episode_length_s=10", "env.episode_length_s", 10),
    (" env.decimation = 2", "env.decimation", 2),
    ("terrain.types=[flat,rugged]", "terrain.types", ["flat", "rugged"]),
    ("rewards.flat_orientation=null", "rewards.flat_orientation", None),
    ("scene.terrain_regions=false", "scene.terrain_regions", False),
    ("agent.run_name=a=b", "agent.run_name", "a=b"),  # the first '=' splits
    # exponent notation is a float, as in Python (PyYAML alone reads 1e-3, 5E4 and 1.0e3 as strings)
    ("agent.algorithm.learning_rate=1e-3", "agent.algorithm.learning_rate", 0.001),
    ("agent.algorithm.learning_rate=1.0e-3", "agent.algorithm.learning_rate", 0.001),
    ("agent.algorithm.learning_rate=-2.5E4", "agent.algorithm.learning_rate", -25000.0),
    ("agent.algorithm.learning_rate=.5e+1", "agent.algorithm.learning_rate", 5.0),
    ("agent.run_name='1e-3'", "agent.run_name", "1e-3"),  # quoted: a string
    ("agent.run_name=1e-3x", "agent.run_name", "1e-3x"),
])
def test_set_pair_parses_the_value_as_yaml(text, key, value):
    parsed = set_pair(text)
    assert parsed == (key, value) and type(parsed[1]) is type(value)


@pytest.mark.parametrize(("text", "why"), [
    ("env.episode_length_s", "has no '='"),
    ("=10", "empty key"),
    ("env..episode_length_s=10", "empty key"),
    ("env.=10", "empty key"),
    ("env.episode_length_s=", "no value"),
    ("env.episode_length_s=  ", "no value"),
    ("terrain.types=[flat,", "not YAML"),
    ("env.seed={a: 1", "not YAML"),
])
def test_set_pair_refuses_malformed_pairs(text, why):
    with pytest.raises(argparse.ArgumentTypeError) as err:
        set_pair(text)
    message = str(err.value)
    assert repr(text) in message and why in message and "expected KEY=VALUE" in message
    assert "\n" not in message


def test_set_overrides_nests_dotted_keys_and_later_pairs_win():
    p = ArgumentParser(prog="x")
    add_set_argument(p)
    args = p.parse_args(["--set", "env.episode_length_s=10", "--set", "agent.algorithm.entropy_coef=0.0",
                         "--set", "env.seed=3", "--set", "env.episode_length_s=12.5", "--set", "env.x.y=1",
                         "--set", "env.x=2"])
    assert set_overrides(args.set) == {"env": {"episode_length_s": 12.5, "seed": 3, "x": 2},
                                       "agent": {"algorithm": {"entropy_coef": 0.0}}}
    assert set_overrides([]) == {} and p.parse_args([]).set == []


def test_merge_overrides_merges_mappings_and_replaces_the_rest():
    flags = {"scene": {"num_workers": 0}, "env": {"episode_length_s": 5.0}}
    pairs = {"scene": {"backend": "cpu"}, "env": {"episode_length_s": 10}, "terminations": None}
    merged = merge_overrides(flags, None, pairs)
    assert merged == {"scene": {"num_workers": 0, "backend": "cpu"}, "env": {"episode_length_s": 10},
                      "terminations": None}
    assert flags == {"scene": {"num_workers": 0}, "env": {"episode_length_s": 5.0}}  # the inputs are not changed
    assert merge_overrides() == {}


def test_overrides_are_checked_like_the_task_file():
    base = load_task("base")
    task = load_task("base", overrides=set_overrides([set_pair("agent.algorithm.entropy_coef=0.005"),
                                                      set_pair("rewards.flat_orientation=null")]))
    assert base.data["agent"]["algorithm"]["entropy_coef"] != 0.005 and "flat_orientation" in base.data["rewards"]
    assert task.data["agent"]["algorithm"]["entropy_coef"] == 0.005 and "flat_orientation" not in task.data["rewards"]
    assert task.source_of("agent.algorithm.entropy_coef") == "<override>"
    for pair, message in (("env.episode_lenght_s=10", "<override>: env.episode_lenght_s: unknown key; allowed: ["),
                          ("env.decimation=2.5", "<override>: env.decimation: must be an integer, got float 2.5"),
                          ("agent.algorithm.entropy_coeff=0", "<override>: agent.algorithm.entropy_coeff: unknown key"),
                          ("envs.seed=1", "<override>: unknown top-level keys ['envs']; allowed: ['env', ")):
        with pytest.raises(ConfigError) as err:
            load_task("base", overrides=set_overrides([set_pair(pair)]))
        assert message in str(err.value)


def test_train_set_reaches_the_run_config(tmp_path):
    """The resolved task.yaml and the agent.yaml PPO ran with carry the overrides (the file's values differ)."""
    task = tmp_path / "tiny.yaml"
    task.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"),
                                    "agent": {"actor": {"hidden_dims": [8]}, "critic": {"hidden_dims": [8]}}}))
    base = load_task(task).data
    assert base["agent"]["algorithm"]["entropy_coef"] != 0.005 and base["env"]["episode_length_s"] != 4.0
    assert base["scene"]["num_workers"] != 0
    run_dir = train.main(["--task", str(task), "--num-envs", "2", "--iterations", "1", "--log-root", str(tmp_path),
                          "--set", "agent.algorithm.entropy_coef=0.005", "--set", "env.episode_length_s=4",
                          "--set", "scene.num_workers=0"])
    resolved = yaml.safe_load((run_dir / "task.yaml").read_text())
    agent = yaml.safe_load((run_dir / "agent.yaml").read_text())
    assert resolved["env"]["episode_length_s"] == 4 and resolved["scene"]["num_workers"] == 0
    assert resolved["agent"]["algorithm"]["entropy_coef"] == 0.005 and agent["algorithm"]["entropy_coef"] == 0.005


def test_train_refuses_a_bad_set_before_anything_is_written(tmp_path, one_line_error):
    line = one_line_error(train.main, ["--task", "base", "--log-root", str(tmp_path), "--set", "env.seed"])
    assert "argument --set: 'env.seed' has no '='" in line
    line = one_line_error(train.main, ["--task", "base", "--log-root", str(tmp_path),
                                       "--set", "agent.algorithm.entropy_coef=much"])
    assert "<override>: agent.algorithm.entropy_coef: must be a number, got str 'much'" in line
    assert not any(tmp_path.iterdir())


def test_eval_set_reaches_the_evaluation_env(tmp_path):
    """Episodes of 0.4 s (20 policy steps at 50 Hz) instead of the base task's 15 s: the recording's length."""
    res = eval_main.main(["--policy", str(POLICY), "--scenario", "simple", "--episodes", "2", "--num-workers", "0",
                          "--out", str(tmp_path), "--set", "env.episode_length_s=0.4"])
    assert load_task("base").data["env"]["episode_length_s"] == 15.0
    assert res["episode_steps"] == 20 and res["episode_length_s"] == pytest.approx(0.4)
    assert res["task_overrides"] == {"env": {"episode_length_s": 0.4}}


def test_eval_refuses_a_section_the_scenario_sets_itself(tmp_path, one_line_error):
    line = one_line_error(eval_main.main, ["--policy", str(POLICY), "--episodes", "2", "--num-workers", "0",
                                           "--out", str(tmp_path), "--set", "rewards.track_lin_vel_xy.weight=2"])
    assert "['rewards']: the evaluation env sets these sections itself" in line
    assert "['env', 'scene', 'actions', 'terminations', 'agent']" in line


def test_closed_loop_set_reaches_the_env():
    overrides = set_overrides([set_pair("terminations.bad_orientation.params.limit_deg=60")])
    assert load_task("base").data["terminations"]["bad_orientation"]["params"]["limit_deg"] == 45.0
    env = closed_loop_episodes.make_env(closed_loop_episodes.commands(2, 0, None), 0.2, seed=0, num_workers=0,
                                        overrides=overrides)
    try:
        assert env.cfg["terminations"]["bad_orientation"]["params"]["limit_deg"] == 60
        assert env.cfg["env"]["episode_length_s"] == 0.2  # --seconds still applies beside the override
    finally:
        env.close()


def test_closed_loop_bad_set_is_one_line(tmp_path, one_line_error):
    line = one_line_error(closed_loop.main, ["--controllers", "rl_baseline", "--episodes", "2",
                                             "--seconds", "0.2", "--out", str(tmp_path),
                                             "--set", "commands.base_velocity.params.max_speed=2"])
    assert "['commands']: the evaluation env sets these sections itself" in line
    line = one_line_error(closed_loop.main, ["--set", "terminations"])
    assert "argument --set: 'terminations' has no '='" in line
