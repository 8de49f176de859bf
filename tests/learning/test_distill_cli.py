"""`python -m dls_quadruped.learning.distill`: a tiny run end to end, resume, and bad input as one
line (issue 10, items 4 and 8). The tiny task ends episodes after 0.5 s (25 steps), so SP is cheap."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml

from dls_quadruped.envs.config import TASKS_DIR
from dls_quadruped.learning import distill
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.student import load_student

EXPERT = Path(__file__).resolve().parents[2] / "docs" / "policies" / "base_actor.pt"


@pytest.fixture
def tiny_task(tmp_path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "env": {"episode_length_s": 0.5},
                                    "scene": {"num_workers": 0}}))
    return path


def tiny_args(task: Path, run_dir: Path, *extra: str) -> list[str]:
    return ["--task", str(task), "--num-envs", "2", "--epochs", "1", "--datapoints-per-epoch", "40",
            "--test-datapoints", "16", "--test-episodes", "2", "--sp-episodes", "2", "--horizon", "5", "--dt", "0.02",
            "--run-dir", str(run_dir), *extra]


def test_tiny_run_resume_and_outputs(tmp_path, tiny_task, capsys, one_line_error):
    run_dir = tmp_path / "run"
    distill.main(tiny_args(tiny_task, run_dir))
    ckpt = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    assert ckpt["epoch"] == 1 and DiskDataset.open(run_dir / "dataset").total_written == 40
    # rows collected after the checkpoint (a run killed mid-epoch 2) are kept and count for epoch 2
    ds = DiskDataset.open(run_dir / "dataset")
    obs, labels = ds.ordered()
    ds.append(obs[:15], labels[:15])
    distill.main(["--resume", "--run-dir", str(run_dir), "--epochs", "2"])
    out = capsys.readouterr().out
    assert "resumed" in out and "with its stored settings: expert" in out and "first-spline H=5 dt=0.02" in out
    assert "2 epochs; overridden on the command line: train.epochs" in out
    assert DiskDataset.open(run_dir / "dataset").total_written == 80  # 40 + 15 + 25, not 40 + 15 + 40
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert [r["epoch"] for r in metrics["history"]] == [1, 2]
    assert metrics["history"][1]["beta"] == pytest.approx(0.6)  # DAgger, alpha = 0.6, epoch index 1
    sp = metrics["history"][1]["sp"]
    assert sp["episodes"] == 2 and sp["ci95"][0] <= sp["ci95"][1]
    assert (run_dir / "mse_sp.png").stat().st_size > 0 and list(run_dir.glob("events.out.tfevents.*"))
    student, meta = load_student(run_dir / "exported" / "student.pt2")
    assert meta["encoding"]["horizon"] == 5 and meta["output_dim"] == 64 and meta["epochs_trained"] == 2
    # `make distill RESUME=1` passes no settings: the run keeps its 2 epochs (the config file says 30), H = 5
    distill.main(["--resume", "--run-dir", str(run_dir)])
    assert "5 dt=0.02, 2 epochs; nothing overridden" in capsys.readouterr().out
    assert [r["epoch"] for r in json.loads((run_dir / "metrics.json").read_text())["history"]] == [1, 2]
    assert student(torch.zeros(3, 259)).shape == (3, 64)
    # a corrupt dataset is named and nothing else is touched
    (run_dir / "dataset" / "state.json").unlink()
    line = one_line_error(distill.main, ["--resume", "--run-dir", str(run_dir), "--epochs", "3"])
    assert "dataset" in line and "state.json is missing" in line
    assert (run_dir / "checkpoint.pt").is_file() and (run_dir / "dataset" / "obs.npy").is_file()


def test_bad_input_is_one_line(tmp_path, tiny_task, one_line_error, save_policy):
    run = tmp_path / "r"
    assert "unknown encoding" in one_line_error(distill.main, tiny_args(tiny_task, run, "--encoding", "cubic-spline"))
    line = one_line_error(distill.main, tiny_args(tiny_task, run, "--horizon", "0"))
    assert "encoding.horizon: must be >= 1, got 0" in line
    assert ">= 4 with a spline" in one_line_error(distill.main, tiny_args(tiny_task, run, "--horizon", "3"))
    assert "must be > 0" in one_line_error(distill.main, tiny_args(tiny_task, run, "--dt", "0"))
    line = one_line_error(distill.main, tiny_args(tiny_task, run, "--dt", "0.03"))
    assert "0.03 s is not a multiple of the env step 0.02 s" in line
    line = one_line_error(distill.main, tiny_args(tiny_task, run, "--expert", str(tmp_path / "none.pt")))
    assert "none.pt not found" in line
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    assert "not a TorchScript actor" in one_line_error(distill.main, tiny_args(tiny_task, run, "--expert",
                                                                               str(tmp_path / "junk.pt")))
    expert = save_policy(torch.nn.Linear(72, 28), 72, tmp_path / "o.pt2")
    line = one_line_error(distill.main, tiny_args(tiny_task, run, "--expert", str(expert)))
    assert "takes 72 observations; the task gives 259" in line
    expert = save_policy(torch.nn.Linear(259, 12), 259, tmp_path / "a.pt2")
    line = one_line_error(distill.main, tiny_args(tiny_task, run, "--expert", str(expert)))
    assert "outputs (12,) actions per robot; the task needs 28" in line
    assert not run.exists()  # nothing was written for a refused run
    assert "--resume: no checkpoint.pt" in one_line_error(distill.main, ["--resume", "--run-dir", str(run)])
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"garbage")
    assert "is unreadable" in one_line_error(distill.main, ["--resume", "--run-dir", str(run)])
    assert "is not empty" in one_line_error(distill.main, tiny_args(tiny_task, run))


def test_expert_fixture_exists():
    assert EXPERT.is_file()
