"""play: the zero action trots; with no --checkpoint the newest checkpoint of the latest run plays; exported and
committed TorchScript actors play; bad input (nothing to play, another task's policy, an unknown task, a
malformed --set) is one line and exit 2."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from dls_quadruped.envs.config import TASKS_DIR, available_tasks
from dls_quadruped.learning import play, train

REPO = Path(__file__).resolve().parents[2]
COMMITTED = REPO / "docs" / "policies" / "base_actor.pt"
SHORT = ["--seconds", "0.2", "--num-envs", "2", "--no-video"]
NO_HEIGHT_SCAN = "observations.policy.terms.height_scan=null"
POLICY_OBS, SCAN_OBS = 259, 17 * 11  # tasks/_common.yaml: 3+3+3+12+12+28+4+4+187+3; the 17 x 11 height scan


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[Path, Path]:
    """(task file, run directory) of a one-iteration run of the base task with 8-unit networks."""
    root = tmp_path_factory.mktemp("tiny")
    task = root / "tiny.yaml"
    task.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "scene": {"num_workers": 0},
                                    "agent": {"actor": {"hidden_dims": [8]}, "critic": {"hidden_dims": [8]}}}))
    run_dir = train.main(["--task", str(task), "--num-envs", "2", "--iterations", "1", "--log-root",
                          str(root / "runs")])
    return task, run_dir


def test_play_writes_plots_and_trot_contacts(tmp_path):
    out = play.main(["--task", "base", "--zero-action", "--seconds", "1.0", "--num-envs", "2", "--out", str(tmp_path),
                     "--no-video"])
    assert (out / "tracking.png").is_file() and (out / "gait.png").is_file()
    trace = np.load(out / "play.npz")
    c = trace["contact"]
    assert c.shape == (50, 4) and trace["command"].shape == (50, 3)
    assert trace["action"].shape == (50, 28) and not trace["action"].any()
    # trot: diagonal pairs (FL, RR) and (FR, RL) agree most of the time, the two pairs mostly differ
    assert (c[:, 0] == c[:, 3]).mean() > 0.7 and (c[:, 1] == c[:, 2]).mean() > 0.7
    assert (c[:, 0] != c[:, 1]).mean() > 0.3


def test_play_set_reaches_the_commands(tmp_path):
    """A yaw-rate range of one value and no standing robots: every recorded command has exactly that yaw rate
    (the file's range is [-1, 1]) and a planar speed within the overridden max_speed."""
    out = play.main(["--task", "base", "--zero-action", *SHORT, "--out", str(tmp_path),
                     "--set", "commands.base_velocity.params.ang_vel_z=[0.25,0.25]",
                     "--set", "commands.base_velocity.params.max_speed=0.3",
                     "--set", "commands.base_velocity.params.standing_fraction=0.0"])
    cmd = np.load(out / "play.npz")["command"]
    np.testing.assert_array_equal(cmd[:, 2], np.float32(0.25))
    assert (np.hypot(cmd[:, 0], cmd[:, 1]) <= 0.3 + 1e-6).all()


def test_play_default_is_the_newest_readable_checkpoint_of_the_latest_run(tiny, tmp_path, capsys):
    task, run_dir = tiny
    task_dir = tmp_path / "runs" / "tiny"
    older, latest = task_dir / "older", task_dir / "latest"
    for run, names in ((older, ["model_9.pt"]), (latest, ["model_0.pt", "model_3.pt"])):
        run.mkdir(parents=True)
        for name in names:
            shutil.copy(run_dir / "model_0.pt", run / name)
        shutil.copy(run_dir / "agent.yaml", run / "agent.yaml")
    (latest / "model_7.pt").write_bytes(b"killed mid-save")  # the highest iteration, unreadable: skipped
    newer = ((latest / n, 2e9) for n in ("model_0.pt", "model_3.pt", "model_7.pt"))
    for path, t in ((older / "model_9.pt", 1e9), *newer):
        os.utime(path, (t, t))
    capsys.readouterr()
    out = play.main(["--task", str(task), "--log-root", str(tmp_path / "runs"), *SHORT])
    printed = capsys.readouterr().out
    assert f"[play] note: skipping unreadable checkpoint {latest / 'model_7.pt'}" in printed
    assert f"playing {latest / 'model_3.pt'}" in printed
    assert out == latest / "play" and (out / "play.npz").is_file() and (out / "gait.png").is_file()
    action = np.load(out / "play.npz")["action"]
    assert np.isfinite(action).all() and action.any()  # the policy acted, not the zero action


def test_play_takes_exported_and_committed_actors(tiny, tmp_path):
    task, run_dir = tiny
    exported = run_dir / "exported" / "policy.pt2"
    out = play.main(["--task", str(task), "--checkpoint", str(exported), "--log-root", str(run_dir.parents[1]), *SHORT])
    assert out == run_dir / "exported" / "play" and np.load(out / "play.npz")["action"].any()
    # a committed policy lies outside the log root: its folder gets nothing, the output goes under the task's runs
    before = sorted(COMMITTED.parent.iterdir())
    out = play.main(["--task", "base", "--checkpoint", str(COMMITTED), "--log-root", str(tmp_path), *SHORT])
    assert out == tmp_path / "base" / "play" / "base_actor" and (out / "tracking.png").is_file()
    assert sorted(COMMITTED.parent.iterdir()) == before


def test_play_without_checkpoint_is_one_line(tmp_path, one_line_error):
    line = one_line_error(play.main, ["--task", "base", "--log-root", str(tmp_path), *SHORT])
    assert f"no checkpoint under {tmp_path / 'base'}/; train one with make train TASK=base" in line
    assert "--checkpoint" in line
    assert not any(tmp_path.iterdir())  # nothing written


def test_play_checkpoint_of_another_task_names_both(tiny, one_line_error):
    _, run_dir = tiny
    # the same observation layout, another task: a model_<it>.pt says which task it was trained on
    line = one_line_error(play.main, ["--task", "base", "--checkpoint", str(run_dir / "model_0.pt"), *SHORT])
    assert "--checkpoint" in line and "trained on task 'tiny', this is task 'base'" in line
    # another observation size: the exported actor's input width against the env's
    line = one_line_error(play.main, ["--task", "base", "--checkpoint", str(run_dir / "exported" / "policy.pt2"),
                                      "--set", NO_HEIGHT_SCAN, *SHORT])
    assert f"takes {POLICY_OBS} observation inputs, the env of task base gives {POLICY_OBS - SCAN_OBS}" in line


def test_play_unknown_task_lists_the_tasks(tmp_path, one_line_error):
    line = one_line_error(play.main, ["--task", "nope", "--log-root", str(tmp_path), *SHORT])
    assert line.endswith(f"unknown task 'nope'; available: {available_tasks()}")


@pytest.mark.parametrize("pair", ["env.episode_length_s", "=10", "env..episode_length_s=10", "env.episode_length_s=",
                                  "env.episode_length_s=[1,"])
def test_play_malformed_set_is_one_line(pair, one_line_error):
    line = one_line_error(play.main, ["--task", "base", "--zero-action", "--set", pair])
    assert f"error: argument --set: {pair!r}" in line and "expected KEY=VALUE" in line


def test_play_set_is_checked_like_the_task_file(one_line_error):
    line = one_line_error(play.main, ["--task", "base", "--zero-action", "--set", "env.episode_lenght_s=10"])
    assert "<override>: env.episode_lenght_s: unknown key; allowed: [" in line and "'episode_length_s'" in line
