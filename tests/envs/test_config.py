"""Task loading: inheritance, deep merge, and errors that name the file, key and allowed values."""

from __future__ import annotations

from pathlib import Path

import pytest

from dls_quadruped.envs.config import TASKS_DIR, ConfigError, load_task
from dls_quadruped.envs.managers.base import resolve_terms
from dls_quadruped.envs.mdp import rewards as reward_mdp

TASKS = ("base", "rough", "speed", "climb")


def _write(tmp: Path, name: str, text: str) -> Path:
    p = tmp / name
    p.write_text(text)
    return p


def test_inherit_merge_and_delete(tmp_path):
    _write(tmp_path, "parent.yaml", "rewards:\n  a: {weight: 1.0, params: {sigma: 0.5}}\n  b: {weight: 2.0}\n")
    child = _write(tmp_path, "child.yaml", "inherit: parent.yaml\nrewards:\n  a: {params: {sigma: 0.3}}\n  b: null\n")
    task = load_task(child, validate=False)  # fake term names: only the merge is under test
    assert task.data["rewards"] == {"a": {"weight": 1.0, "params": {"sigma": 0.3}}}
    assert task.source_of("rewards.a.weight").endswith("parent.yaml")
    assert task.source_of("rewards.a.params.sigma").endswith("child.yaml")


def test_unknown_param_names_file_key_and_allowed(tmp_path):
    p = _write(tmp_path, "t.yaml", "rewards:\n  track_lin_vel_xy: {weight: 1.0, params: {sigm: 0.5}}\n")
    task = load_task(p, validate=False)  # resolve_terms itself is under test
    with pytest.raises(ConfigError) as err:
        resolve_terms(task, "rewards", reward_mdp, {"weight": ...})
    msg = str(err.value)
    assert "t.yaml" in msg and "rewards.track_lin_vel_xy.params.sigm" in msg and "sigma" in msg


def test_unknown_term_function_and_key(tmp_path):
    p = _write(tmp_path, "t.yaml", "rewards:\n  speed: {func: go_fast, weight: 1.0}\n")
    with pytest.raises(ConfigError, match=r"t.yaml: rewards.speed.func: unknown term function "
                                          r"'go_fast'.*track_lin_vel_xy"):
        resolve_terms(load_task(p, validate=False), "rewards", reward_mdp, {"weight": ...})
    p = _write(tmp_path, "u.yaml", "rewards:\n  lin_vel_z: {wieght: 1.0}\n")
    with pytest.raises(ConfigError, match=r"u.yaml: rewards.lin_vel_z.wieght: unknown key; allowed"):
        resolve_terms(load_task(p, validate=False), "rewards", reward_mdp, {"weight": ...})
    p = _write(tmp_path, "v.yaml", "rewardz: {}\n")
    with pytest.raises(ConfigError, match="unknown top-level keys"):
        load_task(p)


def test_unknown_task_lists_available():
    with pytest.raises(ConfigError, match="available: .*'base'"):
        load_task("no_such_task")


TABLE6 = (1e-3, 0.99, 0.95, 5, 4, 0.2, 0.005, 0.1, "adaptive")
"""Thesis Table 6: lr, gamma, lambda, epochs, mini-batches, clip, entropy, desired KL, schedule."""


def _ppo(agent: dict) -> tuple:
    alg = agent["algorithm"]
    return (alg["learning_rate"], alg["gamma"], alg["lam"], alg["num_learning_epochs"], alg["num_mini_batches"],
            alg["clip_param"], alg["entropy_coef"], alg["desired_kl"], alg["schedule"])


@pytest.mark.parametrize("name", TASKS)
def test_tasks_resolve_and_follow_table6_but_the_entropy_bonus(name):
    task = load_task(name)
    resolve_terms(task, "rewards", reward_mdp, {"weight": ...})
    agent = task.data["agent"]
    assert agent["actor"]["hidden_dims"] == [512, 256, 128] == agent["critic"]["hidden_dims"]
    assert agent["actor"]["activation"] == "elu" and agent["num_steps_per_env"] == 24
    assert _ppo(agent) == (*TABLE6[:6], 0.0, *TABLE6[7:])  # the default recipe: no entropy bonus
    assert agent["actor"]["distribution_cfg"]["init_std"] == 1.0


def test_the_thesis_variant_is_table6_exactly(tmp_path):
    thesis = load_task("base_thesis").data["agent"]
    assert _ppo(thesis) == TABLE6
    assert thesis["actor"]["distribution_cfg"] == {"class_name": "GaussianDistribution", "init_std": 1.0,
                                                  "std_type": "scalar", "std_range": [1e-6, 1e6]}  # rsl-rl's defaults
    # the fragment applies to any task: rough with Table 6
    path = tmp_path / "rough_thesis.yaml"
    path.write_text(f"inherit: [{TASKS_DIR / 'rough.yaml'}, {TASKS_DIR / '_ppo_thesis.yaml'}]\n")
    rough_thesis, rough = load_task(path), load_task("rough")
    assert _ppo(rough_thesis.data["agent"]) == TABLE6
    assert {k: v for k, v in rough_thesis.data.items() if k != "agent"} == \
        {k: v for k, v in rough.data.items() if k != "agent"}


@pytest.mark.parametrize("task", ["climb", "rough"])
def test_finetune_is_its_task_without_entropy_and_with_a_std_cap(task):
    """tasks/<task>_finetune.yaml (climb's second stage; rough retrained without the bonus) changes only the
    agent's exploration: the env, rewards and curricula are the task's, and rsl-rl's own signature check
    (agent_config) accepts the std clamp."""
    from dls_quadruped.envs.agent_config import check_agent_section

    climb, fine = load_task(task), load_task(f"{task}_finetune")
    assert {k: v for k, v in fine.data.items() if k != "agent"} == {k: v for k, v in climb.data.items() if k != "agent"}
    assert fine.data["agent"]["algorithm"]["entropy_coef"] == 0.0
    assert fine.data["agent"]["actor"]["distribution_cfg"]["std_range"] == [0.05, 1.0]
    check_agent_section(fine)  # load_task ran it too; explicit here
