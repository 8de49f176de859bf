"""What the Makefile's recipes run, read with ``make -n`` (nothing is executed): every printed command is whole
(no stray line continuation), and ``make distill RESUME=1`` passes only the settings given on the command line,
so a resumed run keeps its stored expert, encoding and epochs (``learning/distill.py`` reads them from the
run's ``distill.yaml``)."""

from __future__ import annotations

import itertools
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="GNU make is not installed")


def dry_run(*args: str, env: dict[str, str] | None = None) -> str:
    """``make -n ARGS`` in the repository (make variables of the calling environment left out): the commands
    make would run."""
    clean = {k: v for k, v in os.environ.items() if not re.match(r"^[A-Z_]+$", k) or k in ("PATH", "HOME")}
    out = subprocess.run(["make", "-n", *args], cwd=REPO, capture_output=True, text=True, timeout=60, check=True,
                         env={**clean, **(env or {})})
    return out.stdout


def module_line(output: str, module: str) -> str:
    """The one printed command that runs ``python -m module``."""
    (line,) = [line for line in output.splitlines() if f"-m {module} " in line + " "]
    return line


def targets() -> list[str]:
    text = (REPO / "Makefile").read_text()
    found = re.findall(r"^([a-z][\w-]*)\s*:(?!=)", text, flags=re.MULTILINE)
    return sorted(set(found) - {"clean"})


def test_every_target_prints_whole_commands():
    assert {"train", "play", "eval", "select", "distill", "wheelhouse", "bench-device"} <= set(targets())
    broken = {}
    for target in targets():
        lines = [*dry_run(target).splitlines(), ""]
        # a continuation is whole when a non-blank line follows it; an empty option at a line's end left `\`
        bad = [line for line, after in itertools.pairwise(lines) if line.rstrip().endswith("\\") and not after.strip()]
        if bad:
            broken[target] = bad
    assert not broken, broken


def test_play_and_train_print_one_line_without_empty_options():
    assert module_line(dry_run("play"), "dls_quadruped.learning.play").endswith("--task base --seconds 10")
    line = module_line(dry_run("train", "SET=env.episode_length_s=5"), "dls_quadruped.learning.train")
    assert line.endswith("--device cpu --set 'env.episode_length_s=5'") and "  " not in line


def test_distill_passes_every_setting_for_a_new_run():
    line = module_line(dry_run("distill"), "dls_quadruped.learning.distill")
    for flag in ("--expert docs/policies/base_actor.pt", "--encoding first-spline", "--horizon 10", "--dt 0.02",
                 "--algo dagger", "--epochs 30", "--num-envs 128"):
        assert flag in line, (flag, line)
    assert "--resume" not in line


def test_distill_resume_keeps_the_runs_settings_unless_given():
    line = module_line(dry_run("distill", "RESUME=1"), "dls_quadruped.learning.distill")
    assert line.endswith("-m dls_quadruped.learning.distill --out results/distill --resume"), line
    line = module_line(dry_run("distill", "RESUME=1", "EPOCHS=40"), "dls_quadruped.learning.distill")
    assert "--epochs 40" in line and "--expert" not in line and "--encoding" not in line
    line = module_line(dry_run("distill", "RESUME=1", env={"EXPERT": "x.pt2"}), "dls_quadruped.learning.distill")
    assert "--expert x.pt2" in line and "--epochs" not in line
