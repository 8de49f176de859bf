"""A run continued from a checkpoint file in another directory, by a fresh process, takes the iteration
the uninterrupted run would have taken (issue 25, items 4 and 6).

The tiny task (``tests/conftest.py``'s ``write_task``) ends episodes after 25 policy steps, so at the end of an
iteration (24 steps per env) robots are in the middle of their episodes, some have fallen and been
reset, and the curricula move every iteration: everything a resume could lose is in play.
"""

from __future__ import annotations

import random
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dls_quadruped.cli import UserError
from dls_quadruped.learning import train
from dls_quadruped.learning.runner import read_checkpoint

REPO = Path(__file__).resolve().parents[2]
WALL_CLOCK = {"tot_time", "versions", "infos"}
"""Keys that hold wall time or library versions, not training state."""


def differences(a, b, where: str = "") -> list[str]:
    """Paths at which two checkpoints (nested dicts/lists/tuples of tensors, arrays, numbers) differ
    bit for bit (a tensor's dtype and shape included)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where}: keys {sorted(set(a) ^ set(b), key=str)}"]
        return [d for k in a if k not in WALL_CLOCK for d in differences(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{where}: length {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{where}[{i}]")]
    if isinstance(a, torch.Tensor):
        same = isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
        return [] if same else [where]
    if isinstance(a, np.ndarray):
        return [] if isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b) else [where]
    return [] if a == b else [where]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory, write_task, train_args):
    """Three iterations in one process; a checkpoint after each."""
    tmp = tmp_path_factory.mktemp("uninterrupted")
    task = write_task(tmp)
    run_dir = train.main(train_args(task, tmp / "run", "--iterations", "3", "--seed", "7"))
    return task, run_dir


def test_resumed_iteration_equals_the_uninterrupted_one(uninterrupted, tmp_path, train_args):
    task, run_dir = uninterrupted
    portable = tmp_path / "elsewhere" / "tiny_resume.pt"  # e.g. committed beside the policies
    portable.parent.mkdir()
    shutil.copy(run_dir / "model_1.pt", portable)
    resumed_dir = tmp_path / "resumed"
    # a fresh process: no torch/numpy/python RNG, module cache or simulator left over from the first run
    out = subprocess.run([sys.executable, "-m", "dls_quadruped.learning.train",
                          *train_args(task, resumed_dir, "--iterations", "1", "--resume-from", str(portable))],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "resumed from" in out.stdout and "note:" not in out.stdout
    assert sorted(p.name for p in resumed_dir.glob("model_*.pt")) == ["model_2.pt"]

    before, want, got = (read_checkpoint(p) for p in (run_dir / "model_1.pt", run_dir / "model_2.pt",
                                                      resumed_dir / "model_2.pt"))
    assert differences(want, got) == []
    # the comparison is not vacuous: iteration 2 moved the weights, Adam's moments, the curricula,
    # the simulator and torch's RNG, and it reset robots (episode counters); numpy and Python draw
    # nothing in training, but a fresh process seeds them anew, so their equality above is a check too
    moved = differences(before, want)
    for part in (".actor_state_dict.mlp.0.weight", ".critic_state_dict.obs_normalizer._mean",
                 ".optimizer_state_dict.state.0.exp_avg_sq", ".env_state.curriculum_values.speed",
                 ".env_state.episodes.sim.shards.mj.qpos", ".env_state.episodes.sim.shards.mj.qacc_warmstart",
                 ".env_state.episodes.sim.shards.controller.phase", ".env_state.schedule.episode",
                 ".env_state.rng_cpu", ".logger_state.tot_timesteps"):
        assert part in moved, (part, moved)
    assert got["iter"] == 2 and got["logger_state"]["tot_timesteps"] == 3 * 4 * 24


def test_resume_without_the_episodes_in_progress_differs(uninterrupted, tmp_path, train_args):
    """The control: the old resume (every robot restarts its episode) does *not* repeat iteration 2,
    so the test above would see a missing piece of state."""
    task, run_dir = uninterrupted
    ckpt = read_checkpoint(run_dir / "model_1.pt")
    del ckpt["env_state"]["episodes"]
    portable = tmp_path / "old_style.pt"
    torch.save(ckpt, portable)
    state = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    try:
        resumed = train.main(train_args(task, tmp_path / "resumed", "--iterations", "1", "--resume-from",
                                        str(portable)))
    finally:
        torch.set_rng_state(state[0]), np.random.set_state(state[1]), random.setstate(state[2])
    moved = differences(read_checkpoint(run_dir / "model_2.pt"), read_checkpoint(resumed / "model_2.pt"))
    assert ".actor_state_dict.mlp.0.weight" in moved and ".env_state.episodes.sim.shards.mj.qpos" in moved


def test_checkpoint_copy_writes_every_checkpoint_to_one_file(tmp_path, write_task, train_args):
    task = write_task(tmp_path)
    copy = tmp_path / "policies" / "tiny_resume.pt"
    copy.parent.mkdir()
    run_dir = train.main(train_args(task, tmp_path / "run", "--iterations", "2", "--checkpoint-copy", str(copy)))
    assert differences(read_checkpoint(run_dir / "model_1.pt"), read_checkpoint(copy)) == []
    assert not list(copy.parent.glob("*.tmp"))


@pytest.mark.parametrize("extra, message", [
    (("--resume",), r"--resume-from continues from a checkpoint file in a new run directory"),
    (("--seed", "3"), r"--seed 3: .*model_1.pt was trained with seed 7; give --seed 7"),
])
def test_resume_from_bad_flags_is_one_line_and_writes_nothing(uninterrupted, tmp_path, extra, message, train_args):
    task, run_dir = uninterrupted
    target = tmp_path / "resumed"
    with pytest.raises(UserError, match=message):
        train.main(train_args(task, target, "--resume-from", str(run_dir / "model_1.pt"), *extra))
    assert not target.exists()


def test_resume_from_another_task_is_refused_naming_both(uninterrupted, tmp_path, write_task, train_args):
    _, run_dir = uninterrupted
    other = write_task(tmp_path, "other")  # the same observation and action sizes, another task
    target = tmp_path / "resumed"
    with pytest.raises(UserError, match=r"^--resume-from: .*model_1.pt was trained on task 'tiny', "
                                        r"this is task 'other'$"):
        train.main(train_args(other, target, "--resume-from", str(run_dir / "model_1.pt")))
    assert not any(p.name.startswith(("model_", "events")) for p in target.iterdir())


def test_resume_from_a_truncated_file_is_one_line(uninterrupted, tmp_path, train_args):
    _, run_dir = uninterrupted
    broken = tmp_path / "broken.pt"
    broken.write_bytes((run_dir / "model_1.pt").read_bytes()[:1000])
    with pytest.raises(UserError, match=r"^--resume-from: cannot read .*broken.pt: "):
        train.main(train_args(REPO / "tasks" / "base.yaml", tmp_path / "resumed", "--resume-from", str(broken)))
    assert not (tmp_path / "resumed").exists()


def test_resume_without_num_envs_keeps_the_checkpoints_robots(uninterrupted, tmp_path, train_args):
    """The tiny task's own ``env.num_envs`` is not the 4 robots it was trained with: a continued run without
    ``--num-envs`` keeps the checkpoint's 4 (and so continues exactly), instead of restarting every episode
    on the task's default."""
    task, run_dir = uninterrupted
    assert train.checkpoint_num_envs(read_checkpoint(run_dir / "model_1.pt")) == 4
    assert train.checkpoint_num_envs({"iter": 3}) is None  # a checkpoint without episodes: the task's count
    resumed_dir = tmp_path / "resumed"
    argv = train_args(task, resumed_dir, "--iterations", "1", "--resume-from", str(run_dir / "model_1.pt"))
    i = argv.index("--num-envs")
    del argv[i:i + 2]
    train.main(argv)
    got = read_checkpoint(resumed_dir / "model_2.pt")
    assert got["env_state"]["episodes"]["num_envs"] == 4
    assert differences(read_checkpoint(run_dir / "model_2.pt"), got) == []
