"""Training faults: kills, signals, unreadable checkpoints, wrong-task resumes, occupied run dirs.

The tiny task (``tests/conftest.py``'s ``write_task``) ends every episode after 0.5 s (25 policy
steps), so each PPO iteration (24 steps per env) resets robots and moves the curricula: the speed
range grows by 0.05 m/s per batch of resets and the penalty switch flips on the first reset
(threshold -1).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from dls_quadruped.cli import UserError
from dls_quadruped.learning import train
from dls_quadruped.learning.runner import checkpoints, new_run_dir, read_checkpoint

REPO = Path(__file__).resolve().parents[2]
def test_default_save_interval_follows_run_length():
    assert train.default_save_interval(30, 50) == 3  # issue 9: 50 lost 15 of 16 iterations of a 30-iteration run
    assert train.default_save_interval(5, 50) == 1
    assert train.default_save_interval(10_000, 50) == 50


def test_run_dirs_are_unique_within_one_second(tmp_path):
    dirs = {new_run_dir(tmp_path) for _ in range(3)}
    assert len(dirs) == 3 and all(d.is_dir() for d in dirs)


def test_non_empty_run_dir_refused_without_resume(tmp_path, write_task, train_args):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "model_7.pt").write_bytes(b"precious")
    with pytest.raises(UserError, match="not empty; add --resume"):
        train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1"))
    assert (run_dir / "model_7.pt").read_bytes() == b"precious" and len(list(run_dir.iterdir())) == 1


@pytest.mark.parametrize("flag", [["--num-envs", "0"], ["--iterations", "0"], ["--save-interval", "-1"],
                                  ["--num-workers", "two"], ["--save-every-min", "nan"]])
def test_bad_numbers_on_the_command_line_are_usage_errors(flag, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(flag)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag[0] in err[0]


def test_resume_skips_unreadable_checkpoint_cleans_tmp_and_restores_env_state(tmp_path, capsys, write_task, train_args,
                                                                              printed_curriculum):
    task = write_task(tmp_path)
    run_dir = tmp_path / "run"
    train.main(train_args(task, run_dir, "--iterations", "3"))
    assert sorted(it for it, _ in checkpoints(run_dir)) == [0, 1, 2]
    good = read_checkpoint(run_dir / "model_1.pt")
    env_state = good["env_state"]
    assert env_state["curriculum_values"]["penalties"] == 1.0  # switched on: threshold -1
    assert env_state["reward_weights"]["action_rate"] == pytest.approx(-2.5e-5)
    speed = env_state["curriculum_values"]["speed"]
    assert speed > 0.5 and env_state["command_params"]["lin_vel_x"][1] == pytest.approx(speed)
    # a kill during the save of iteration 2 leaves a .tmp; a disk error a truncated model_2.pt
    (run_dir / "model_3.pt.tmp").write_bytes(b"half a checkpoint")
    (run_dir / "model_2.pt").write_bytes(b"\x80\x02garbage")
    capsys.readouterr()
    train.main(train_args(task, run_dir, "--iterations", "1", "--resume"))
    out = capsys.readouterr().out
    notes = [line for line in out.splitlines() if "skipping unreadable checkpoint" in line]
    assert len(notes) == 1 and "model_2.pt" in notes[0]
    assert f"resumed from {run_dir / 'model_1.pt'} at iteration 2" in out
    line = next(x for x in out.splitlines() if "resumed from" in x)
    assert printed_curriculum(line) == pytest.approx(env_state["curriculum_values"])
    assert not list(run_dir.glob("*.tmp"))
    resumed = read_checkpoint(run_dir / "model_2.pt")
    assert resumed["iter"] == 2
    # the curriculum went on from the saved state, not from the task's initial one
    assert resumed["env_state"]["curriculum_values"]["speed"] >= speed
    assert resumed["env_state"]["reward_weights"]["action_rate"] == pytest.approx(-2.5e-5)


def test_resume_onto_another_task_is_refused_before_writing(tmp_path, write_task, train_args):
    small = write_task(tmp_path, "small", observations={"policy": {"terms": {"height_scan": None}}})
    run_dir = tmp_path / "run"
    train.main(train_args(small, run_dir, "--iterations", "1"))
    before = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
    with pytest.raises(UserError, match=r"trained with observations \{'policy': 72\}.*'policy': 259"):
        train.main(train_args(write_task(tmp_path), run_dir, "--iterations", "1", "--resume"))
    after = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
    assert after == before


def _spawn_training(train_args, task: Path, run_dir: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "dls_quadruped.learning.train", *train_args(task, run_dir, *extra)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_for(run_dir: Path, iteration: int, proc: subprocess.Popen, timeout_s: float = 240.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not (run_dir / f"model_{iteration}.pt").exists():
        assert proc.poll() is None, proc.stdout.read()
        assert time.monotonic() < deadline, "training made no progress"
        time.sleep(0.05)


def test_sigkill_mid_run_then_resume_continues_from_last_checkpoint(tmp_path, write_task, train_args,
                                                                    printed_curriculum):
    task = write_task(tmp_path)
    run_dir = tmp_path / "run"
    proc = _spawn_training(train_args, task, run_dir, "--iterations", "200")
    _wait_for(run_dir, 2, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    last_it, last_path = max(checkpoints(run_dir))
    assert 2 <= last_it < 199
    saved = read_checkpoint(last_path)["env_state"]
    resumed = subprocess.run(
        [sys.executable, "-m", "dls_quadruped.learning.train",
         *train_args(task, run_dir, "--iterations", "1", "--resume")],
        check=False, cwd=REPO, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    line = next(x for x in resumed.stdout.splitlines() if "resumed from" in x)
    assert f"model_{last_it}.pt at iteration {last_it + 1}" in line
    assert printed_curriculum(line) == pytest.approx(saved["curriculum_values"])
    assert read_checkpoint(run_dir / f"model_{last_it + 1}.pt")["iter"] == last_it + 1


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_saves_the_last_iteration(signum, tmp_path, write_task, train_args):
    run_dir = tmp_path / "run"
    proc = _spawn_training(train_args, write_task(tmp_path), run_dir, "--iterations", "200", "--save-interval", "1000")
    _wait_for(run_dir, 0, proc)  # rsl-rl saves iteration 0 (0 % interval == 0); later ones only on a signal
    proc.send_signal(signum)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, out[-2000:]
    last_it, last_path = max(checkpoints(run_dir))
    assert last_it >= 0 and f"saved {last_path}" in out
    assert read_checkpoint(last_path)["iter"] == last_it
    assert "Traceback" not in out


def test_read_checkpoint_rejects_non_checkpoints(tmp_path):
    (tmp_path / "x.pt").write_bytes(b"not a pickle")
    with pytest.raises(ValueError):
        read_checkpoint(tmp_path / "x.pt")
    torch.save({"weights": 1}, tmp_path / "y.pt")
    with pytest.raises(ValueError, match="not an rsl-rl checkpoint"):
        read_checkpoint(tmp_path / "y.pt")
