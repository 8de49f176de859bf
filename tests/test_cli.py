"""Every command line reports a user error as one line on stderr and exits with 2; no traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import torch
import yaml

from dls_quadruped import demo
from dls_quadruped.core.json_io import dumps
from dls_quadruped.envs.config import TASKS_DIR
from dls_quadruped.eval import __main__ as eval_main
from dls_quadruped.learning import play, train
from dls_quadruped.mpc import run as mpc_run

REPO = Path(__file__).resolve().parents[1]


def _bad_task(tmp_path: Path) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "env": {"decimation": 2.5}}))
    return path


def _checkpoint_of_small_task(tmp_path: Path) -> Path:
    small = tmp_path / "small.yaml"
    small.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "scene": {"num_workers": 0},
                                     "observations": {"policy": {"terms": {"height_scan": None}}},
                                     "agent": {"actor": {"hidden_dims": [8]}, "critic": {"hidden_dims": [8]}}}))
    run_dir = train.main(["--task", str(small), "--num-envs", "2", "--iterations", "1", "--run-dir",
                          str(tmp_path / "small_run")])
    return run_dir / "model_0.pt"


def test_train_user_errors(tmp_path, one_line_error):
    assert "--num-envs: must be >= 1" in one_line_error(train.main, ["--num-envs", "0"])
    assert "--iterations: must be >= 1" in one_line_error(train.main, ["--iterations", "0"])
    assert "unknown task 'nope'" in one_line_error(train.main, ["--task", "nope"])
    line = one_line_error(train.main, ["--task", str(_bad_task(tmp_path))])
    assert "bad.yaml: env.decimation: must be an integer" in line
    assert "--resume: no run" in one_line_error(train.main, ["--resume", "--log-root", str(tmp_path / "x")])
    assert not (tmp_path / "x").exists()


def test_play_user_errors(tmp_path, capsys, one_line_error):
    assert "no such file" in one_line_error(play.main, ["--checkpoint", str(tmp_path / "none.pt")])
    assert "--seconds: must be a finite number" in one_line_error(play.main, ["--seconds", "nan"])
    (tmp_path / "junk.pt").write_bytes(b"junk")
    assert "unreadable" in one_line_error(play.main, ["--checkpoint", str(tmp_path / "junk.pt")])
    ckpt = _checkpoint_of_small_task(tmp_path)
    capsys.readouterr()
    line = one_line_error(play.main, ["--checkpoint", str(ckpt), "--task", "base", "--no-video"])
    assert "'policy': 72" in line and "'policy': 259" in line


def test_mpc_run_and_demo_user_errors(one_line_error):
    assert "--seconds: must be > 0" in one_line_error(mpc_run.main, ["--seconds", "0"])
    assert "--samples: must be >= 1" in one_line_error(mpc_run.main, ["--samples", "0"])
    assert "--vx: must be a finite number" in one_line_error(mpc_run.main, ["--vx", "nan"])
    assert "must cover at least one MPC period" in one_line_error(mpc_run.main, ["--seconds", "0.001"])
    assert "--num-envs: must be >= 1" in one_line_error(demo.main, ["--num-envs", "0"])
    assert "--seconds: must be > 0" in one_line_error(demo.main, ["--seconds", "-1"])


def test_eval_user_errors(tmp_path, one_line_error):
    assert "--episodes: invalid int value" in one_line_error(eval_main.main, ["--policy", "p.pt", "--episodes",
                                                                            "many"])
    line = one_line_error(eval_main.main, ["--policy", str(tmp_path / "none.pt"), "--episodes", "2",
                                          "--num-workers", "0"])
    assert "none.pt not found" in line


def test_train_subprocess_prints_one_line(tmp_path):
    out = subprocess.run([sys.executable, "-m", "dls_quadruped.learning.train", "--task", str(_bad_task(tmp_path))],
                         cwd=REPO, capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        (f"dls_quadruped.learning.train: error: {tmp_path / 'bad.yaml'}: env.decimation: must be an integer, "
         "got float 2.5")]


def test_mpc_run_short_run_writes_strict_json(tmp_path, capsys):
    summary = mpc_run.main(["--seconds", "0.3", "--samples", "64", "--horizon", "4", "--no-video",
                            "--out", str(tmp_path)])
    text = (tmp_path / "summary.json").read_text()

    def refuse(token):
        raise AssertionError(f"non-standard JSON token {token}")

    data = json.loads(text, parse_constant=refuse)
    assert data["velocity_window_s"][1] <= 0.3 + 1e-9 and len(data["mean_velocity_xy"]) == 2
    assert all(map(torch.isfinite, torch.tensor(summary["mean_velocity_xy"])))


def test_strict_json_names_what_was_not_finite():
    text = dumps({"a": 1.0, "b": [float("nan"), 2.0], "c": {"d": float("inf")}, "e": torch.tensor(float("nan"))})
    data = json.loads(text)
    assert data["b"] == [None, 2.0] and data["c"]["d"] is None and data["e"] is None
    assert data["non_finite"] == ["b[0]", "c.d", "e"]


def test_help_shows_every_option_default_once():
    """``--help`` of every entry point prints each option's default (``cli.HelpFormatter``): after the help text,
    alone where an option has no help, never for None / False / empty defaults or where the help names it."""
    import argparse

    from dls_quadruped.cli import ArgumentParser

    p = ArgumentParser(prog="x", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=int, default=4)
    p.add_argument("--seconds", type=float, default=10.0, help="episode length [s]")
    p.add_argument("--out", default=None, help="output folder")
    p.add_argument("--flag", action="store_true", help="a switch")
    p.add_argument("--set", action="append", default=[], help="overrides")
    p.add_argument("--root", default="runs", help="where runs go (default runs/)")
    text = " ".join(p.format_help().split())
    assert "--num-envs NUM_ENVS (default: 4)" in text and "episode length [s] (default: 10.0)" in text
    assert "output folder --flag" in text and "a switch --set" in text and "overrides --root" in text
    assert "(default runs/) (default" not in text and text.count("(default:") == 2

