"""Checkpoints are read without running code from them: what our checkpoints hold loads, a file that names a
function to call is refused with one line before anything runs."""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from dls_quadruped.cli import UserError
from dls_quadruped.envs.config import TASKS_DIR
from dls_quadruped.learning import checkpoint_file, distill, train
from dls_quadruped.learning.checkpoint_file import UnsafeCheckpoint
from dls_quadruped.learning.runner import read_checkpoint

REPO = Path(__file__).resolve().parents[2]


class _MakesADirectory:
    """Pickles as a call of ``os.mkdir(marker)``: had the load run it, ``marker`` would exist."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return os.mkdir, (str(self.marker),)


def _trap(tmp_path: Path, name: str = "model_3.pt", **extra) -> tuple[Path, Path]:
    """A file shaped like an rsl-rl checkpoint that also carries a pickled call; returns (file, marker)."""
    marker = tmp_path / "code_ran"
    path = tmp_path / name
    torch.save({"iter": 3, "actor_state_dict": {"w": torch.zeros(2)}, "infos": _MakesADirectory(marker), **extra},
               path)
    return path, marker


def _assert_equal(a, b) -> None:
    """Nested equality of what ``torch.load(weights_only=False)`` and the safe load give."""
    assert type(a) is type(b)
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            _assert_equal(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _assert_equal(x, y)
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and torch.equal(a, b)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    else:
        assert a == b


@pytest.mark.parametrize("path", sorted((REPO / "docs" / "policies").glob("*_networks.pt")), ids=lambda p: p.name)
def test_committed_networks_load_as_they_did(path):
    _assert_equal(torch.load(path, map_location="cpu", weights_only=False), checkpoint_file.load(path))


def test_the_state_our_checkpoints_hold_round_trips(tmp_path):
    """The non-tensor state of a training checkpoint (numpy's and Python's generators) and of a distillation
    checkpoint (evaluation returns as arrays, metrics as numpy scalars, torch generator states)."""
    rng = np.random.default_rng(0)
    state = {"rng": {"numpy": np.random.get_state(), "python": random.getstate()},
             "reference": {"sp": {"return": rng.standard_normal(5), "len": np.arange(5, dtype=np.int32)}},
             "history": [{"epoch": 1, "test_mse": np.float64(0.25), "sp": None, "ci95": (np.float32(-1), 2.0)}],
             "generator": torch.Generator().manual_seed(3).get_state(), "mask": np.array([True, False]),
             "empty": b"", "ids": torch.arange(4), "half": torch.ones(2, dtype=torch.float16)}
    torch.save(state, tmp_path / "s.pt")
    _assert_equal(torch.load(tmp_path / "s.pt", weights_only=False), checkpoint_file.load(tmp_path / "s.pt"))


def test_a_pickled_call_is_refused_in_one_line_and_never_runs(tmp_path):
    path, marker = _trap(tmp_path)
    with pytest.raises(UnsafeCheckpoint) as err:
        read_checkpoint(path)
    message = str(err.value)
    assert "\n" not in message and "refused: it names" in message and "mkdir, " in message
    assert message.endswith("unpickling it could run code")
    assert not marker.exists()


def test_train_init_from_a_trap_names_the_file(tmp_path):
    path, marker = _trap(tmp_path)
    argv = ["--task", "base", "--num-envs", "4", "--iterations", "1", "--num-workers", "0",
            "--log-root", str(tmp_path / "logs"), "--init-from", str(path)]
    with pytest.raises(UserError) as err:
        train.main(argv)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"--init-from: cannot read {path}: refused: it names")
    assert not marker.exists() and not (tmp_path / "logs").exists()


def test_distill_resume_from_a_trap_names_the_file(tmp_path):
    task = tmp_path / "tiny.yaml"
    task.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "scene": {"num_workers": 0}}))
    run = tmp_path / "run"
    run.mkdir()
    path, marker = _trap(run, "checkpoint.pt", student={})
    with pytest.raises(UserError) as err:
        distill.main(["--task", str(task), "--resume", "--run-dir", str(run)])
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"--resume: {path} is refused: it names")
    assert not marker.exists()
