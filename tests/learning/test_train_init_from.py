"""``train --init-from``: a new run starts from another run's actor and critic, nothing else.

The tiny task of ``test_train_faults`` (hidden layers of 16, 4 robots, 0.5 s episodes) keeps each
run to seconds; its curriculum moves on every reset, so "the env state starts afresh" is visible.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch
import yaml

from dls_quadruped.cli import UserError
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import train
from dls_quadruped.learning.policy_file import load_module
from dls_quadruped.learning.runner import read_checkpoint

REPO = Path(__file__).resolve().parents[2]
STEPS = 24  # agent.num_steps_per_env of _common.yaml
ENVS = 4    # conftest's train_args


@pytest.fixture(scope="module")
def source(tmp_path_factory, write_task, train_args):
    """A 3-iteration run of the tiny task from seed 7 (the runs under test use seed 0, so a fresh
    initialisation differs from it): its last checkpoint has 3 x 4 x 24 normaliser samples and a
    curriculum far from the task's start."""
    tmp = tmp_path_factory.mktemp("source")
    train.main(train_args(write_task(tmp), tmp / "run", "--iterations", "3", "--seed", "7"))  # other initial weights
    return tmp / "run"


def test_init_from_loads_networks_only(source, tmp_path, capsys, write_task, train_args, printed_curriculum):
    src = read_checkpoint(source / "model_2.pt")
    assert int(src["actor_state_dict"]["obs_normalizer.count"]) == 3 * ENVS * STEPS
    assert src["env_state"]["curriculum_values"]["speed"] > 0.6

    run_dir = tmp_path / "new"
    train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1", "--init-from", str(source)))
    line = next(x for x in capsys.readouterr().out.splitlines() if "initialised actor and critic" in x)
    # env state afresh: the curriculum a new env of the task starts with, not the source's
    env = LocomotionEnv(load_task(write_task(tmp_path)), num_envs=ENVS, verbose=False)
    try:
        start = env.curriculum_manager.values_as_floats()
    finally:
        env.close()
    assert printed_curriculum(line) == pytest.approx(start)
    assert start["speed"] < src["env_state"]["curriculum_values"]["speed"] - 0.1
    first = read_checkpoint(run_dir / "model_0.pt")
    assert first["iter"] == 0  # iteration counter afresh (the source was at 2)
    # normalisers go on from the source's statistics and counts: 3 iterations there, 1 here
    for net in ("actor_state_dict", "critic_state_dict"):
        assert int(first[net]["obs_normalizer.count"]) == 3 * ENVS * STEPS + ENVS * STEPS
    fresh = read_checkpoint(_one_iteration_from_scratch(train_args, write_task, tmp_path) / "model_0.pt")
    # the weights start from the source: one PPO iteration moves them far less than the gap between
    # the source and a fresh initialisation
    key = "mlp.0.weight"
    moved = (first["actor_state_dict"][key] - src["actor_state_dict"][key]).abs().max()
    gap = (fresh["actor_state_dict"][key] - src["actor_state_dict"][key]).abs().max()
    assert moved < 0.2 * gap
    # optimiser afresh: Adam's step count is one iteration's updates (5 epochs x 4 mini-batches)
    steps = {int(s["step"]) for s in first["optimizer_state_dict"]["state"].values()}
    assert steps == {20}
    record = yaml.safe_load((run_dir / "init_from.yaml").read_text())
    assert record["iteration"] == 2
    assert record["sha256"] == hashlib.sha256((source / "model_2.pt").read_bytes()).hexdigest()


def _one_iteration_from_scratch(train_args, write_task, tmp_path: Path) -> Path:
    run_dir = tmp_path / "scratch"
    train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1"))
    return run_dir


def test_init_from_with_resume_is_refused(source, tmp_path, write_task, train_args):
    with pytest.raises(UserError, match="only one of them"):
        train.main(train_args(write_task(tmp_path), tmp_path / "r", "--iterations", "1", "--resume",
                              "--init-from", str(source)))


def test_a_run_started_from_another_resumes_from_its_own_checkpoint(source, tmp_path, write_task, train_args):
    """``make train … RESUME=1`` (no INIT_FROM) continues a fine-tuning run where it stopped: its own
    iteration, normaliser counts and record of where it started; the source is not read again."""
    run_dir = tmp_path / "run"
    task = write_task(tmp_path)
    train.main(train_args(task, run_dir, "--iterations", "1", "--init-from", str(source), "--init-std", "0.3"))
    record = (run_dir / "init_from.yaml").read_text()
    train.main(train_args(task, run_dir, "--iterations", "1", "--resume"))
    resumed = read_checkpoint(run_dir / "model_1.pt")
    assert resumed["iter"] == 1
    for net in ("actor_state_dict", "critic_state_dict"):  # 3 source iterations + 1 + 1
        assert int(resumed[net]["obs_normalizer.count"]) == 5 * ENVS * STEPS
    std = resumed["actor_state_dict"]["distribution.std_param"]
    assert (std - 0.3).abs().max() < 0.1  # the resumed run keeps its own std, not the source's
    steps = {int(s["step"]) for s in resumed["optimizer_state_dict"]["state"].values()}
    assert steps == {40}  # Adam went on: 2 iterations x 20 updates
    assert (run_dir / "init_from.yaml").read_text() == record


@pytest.mark.parametrize("what", ["missing", "garbage", "empty_dir"])
def test_init_from_unusable_source_is_one_line_and_writes_nothing(what, tmp_path, write_task, train_args):
    bad = {"missing": tmp_path / "nope.pt", "garbage": tmp_path / "model_1.pt", "empty_dir": tmp_path / "d"}[what]
    if what == "garbage":
        bad.write_bytes(b"\x80\x02garbage")
    if what == "empty_dir":
        bad.mkdir()
    run_dir = tmp_path / "run"
    with pytest.raises(UserError, match="--init-from") as err:
        train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1", "--init-from", str(bad)))
    assert "\n" not in str(err.value) and str(bad) in str(err.value)
    assert not run_dir.exists() or not any(run_dir.iterdir())


def test_init_from_another_observation_size_names_both(source, tmp_path, write_task, train_args):
    small = write_task(tmp_path, "small", observations={"policy": {"terms": {"height_scan": None}}})
    with pytest.raises(UserError, match=r"--init-from: .*observations \{'policy': 259\}.*'policy': 72"):
        train.main(train_args(small, tmp_path / "run", "--iterations", "1", "--init-from", str(source / "model_2.pt")))


def test_committed_base_networks_hold_the_committed_base_actor():
    """docs/policies/base_networks.pt (what the speed, rough and climb experts started from) carries
    exactly the actor exported as docs/policies/base_actor.pt."""
    nets = read_checkpoint(REPO / "docs" / "policies" / "base_networks.pt")
    assert nets["obs_dims"] == {"policy": 259} and nets["num_actions"] == 28
    assert "optimizer_state_dict" not in nets and "env_state" not in nets
    jit = load_module(REPO / "docs" / "policies" / "base_actor.pt").state_dict()
    for key, value in jit.items():
        assert torch.equal(nets["actor_state_dict"][key], value), key


def test_init_std_sets_the_exploration_std(source, tmp_path, write_task, train_args):
    src = read_checkpoint(source / "model_2.pt")["actor_state_dict"]["distribution.std_param"]
    assert (src - 0.3).abs().min() > 0.3  # the tiny task's init std is 1.0: far from the value set below
    run_dir = tmp_path / "run"
    train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1", "--init-from", str(source),
                          "--init-std", "0.3"))
    std = read_checkpoint(run_dir / "model_0.pt")["actor_state_dict"]["distribution.std_param"]
    assert std.shape == src.shape and (std - 0.3).abs().max() < 0.05  # one iteration's updates from 0.3
    assert yaml.safe_load((run_dir / "init_from.yaml").read_text())["init_std"] == 0.3


def test_init_std_without_init_from_is_refused(tmp_path, write_task, train_args):
    with pytest.raises(UserError, match="--init-std .* give --init-from too"):
        train.main(train_args(write_task(tmp_path), tmp_path / "run", "--iterations", "1", "--init-std", "0.5"))


def test_export_of_a_checkpoint_holds_its_actor(source, tmp_path, write_task):
    """``python -m dls_quadruped.learning.export --checkpoint``: how intermediate checkpoints of the
    expert runs were evaluated (docs/train.md)."""
    from dls_quadruped.learning.export import main as export_main

    ckpt = read_checkpoint(source / "model_1.pt")
    program = export_main(["--checkpoint", str(source / "model_1.pt"), "--task", str(write_task(tmp_path)),
                           "--out-dir", str(tmp_path / "out")])
    exported = load_module(program).state_dict()
    assert exported and all(torch.equal(ckpt["actor_state_dict"][k], v) for k, v in exported.items())
    with pytest.raises(UserError, match="--out-dir"):
        export_main(["--checkpoint", str(source / "model_1.pt")])
