"""Every entry point (a module or script with ``if __name__ == "__main__":``) answers ``--help`` with
its usage (exit 0) and a bad flag with exactly one line ``<prog>: error: ...`` on stderr, exit 2, no
traceback (``dls_quadruped/cli.py``).

The entry points are found by reading the sources, so a new one is tested without being listed here.
All of them run in one interpreter (``tests/cli_probe.py``: importing torch, MuJoCo and Pinocchio
once, not once per entry point); one real ``python -m`` run checks the probe sees what a user sees.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BAD_FLAG = "--no-such-flag"
def _has_main_block(path: Path) -> bool:
    """A top-level ``if __name__ == "__main__":`` in the file's code (not in a docstring)."""
    for node in ast.parse(path.read_text()).body:
        test = getattr(node, "test", None)
        if isinstance(node, ast.If) and isinstance(test, ast.Compare) and isinstance(test.left, ast.Name) \
                and test.left.id == "__name__" and len(test.comparators) == 1 \
                and getattr(test.comparators[0], "value", None) == "__main__":
            return True
    return False


def entry_points() -> list[str]:
    """``python -m`` targets of the package (``pkg/__main__.py`` -> ``pkg``) and of the experiment scripts
    (``experiments/x.py`` -> ``experiments.x``)."""
    targets = []
    for path in [*sorted((REPO / "dls_quadruped").rglob("*.py")), *sorted((REPO / "experiments").glob("*.py"))]:
        if _has_main_block(path):
            module = ".".join(path.relative_to(REPO).with_suffix("").parts)
            targets.append(module.removesuffix(".__main__"))
    return targets


TARGETS = entry_points()


def _prog(target: str) -> str:
    return Path(target).name if target.endswith(".py") else target


@pytest.fixture(scope="module")
def probed() -> dict[str, list[dict]]:
    spec = json.dumps({"targets": TARGETS, "argvs": [["--help"], [BAD_FLAG]]})
    out = subprocess.run([sys.executable, str(REPO / "tests" / "cli_probe.py"), spec], cwd=REPO, capture_output=True,
                         text=True, timeout=300, check=True, env={**_env(), "COLUMNS": "100"})
    return json.loads(out.stdout)


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}


def test_every_known_entry_point_is_found():
    expected = {"dls_quadruped.eval", "dls_quadruped.closed_loop", "dls_quadruped.learning.train",
                "dls_quadruped.learning.distill", "dls_quadruped.learning.play", "dls_quadruped.learning.export",
                "dls_quadruped.mpc.run", "dls_quadruped.demo", "dls_quadruped.bench.env", "dls_quadruped.bench.mpc",
                "dls_quadruped.bench.rl_env", "dls_quadruped.bench.dynamics",
                "experiments.table14_warm_start_encodings"}
    assert expected <= set(TARGETS), sorted(expected - set(TARGETS))
    assert "dls_quadruped.cli" not in TARGETS  # its `__main__` is in the docstring only


@pytest.mark.parametrize("target", TARGETS)
def test_help_and_a_bad_flag(probed, target):
    help_run, bad_run = probed[target]
    assert help_run["status"] == 0, help_run["stderr"]
    assert help_run["stdout"].startswith(f"usage: {_prog(target)} "), help_run["stdout"][:200]
    assert help_run["stderr"] == ""
    assert bad_run["status"] == 2, bad_run["stderr"]
    lines = bad_run["stderr"].splitlines()
    assert len(lines) == 1, bad_run["stderr"]
    assert lines[0].startswith(f"{_prog(target)}: error: "), lines
    assert BAD_FLAG in lines[0] or "the following arguments are required" in lines[0], lines
    assert "Traceback" not in bad_run["stderr"] + bad_run["stdout"]


def test_eval_help_shows_the_scenarios_percent_signs(probed):
    assert "below 50 %" in probed["dls_quadruped.eval"][0]["stdout"]  # was: ValueError from argparse's %-formatting


def test_the_probe_sees_what_python_dash_m_shows(probed):
    for argv, index in (["--help"], 0), ([BAD_FLAG], 1):
        real = subprocess.run([sys.executable, "-m", "dls_quadruped.eval", *argv], cwd=REPO, capture_output=True,
                              text=True, timeout=300, check=False, env={**_env(), "COLUMNS": "100"})
        seen = probed["dls_quadruped.eval"][index]
        assert (real.returncode, real.stdout, real.stderr) == (seen["status"], seen["stdout"], seen["stderr"])


@pytest.mark.parametrize(("device", "message"), [
    ("cpux", "argument --device: unknown device 'cpux'; use cpu, cuda or cuda:<index>"),
    ("mps", "argument --device: unsupported device 'mps'; use cpu, cuda or cuda:<index>"),
])
def test_a_device_this_machine_lacks_is_one_line(capsys, device, message):
    from dls_quadruped.cli import run_cli
    from dls_quadruped.eval import __main__ as eval_main

    with pytest.raises(SystemExit) as exit_:
        run_cli(eval_main.main, ["--policy", "p.pt", "--device", device])
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2 and len(lines) == 1 and message in lines[0], lines


def test_cuda_is_refused_where_there_is_none(capsys):
    import torch

    from dls_quadruped.cli import run_cli
    from dls_quadruped.eval import __main__ as eval_main

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    with pytest.raises(SystemExit) as exit_:
        run_cli(eval_main.main, ["--policy", "p.pt", "--device", "cuda"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2 and len(lines) == 1 and "argument --device: cuda: " in lines[0], lines
    assert lines[0].endswith("this torch build has no CUDA; use cpu (see --help)")


def test_help_shows_the_defaults(probed):
    """Every option's default is in ``--help`` (``cli.HelpFormatter``): play's, and nowhere a meaningless one."""
    play_help = " ".join(probed["dls_quadruped.learning.play"][0]["stdout"].split())
    assert "--seconds SECONDS (default: 10.0)" in play_help and "--num-envs NUM_ENVS (default: 4)" in play_help
    assert "--log-root LOG_ROOT train's runs: <log-root>/<task>/<run>/ (default: runs)" in play_help
    noisy = [t for t in TARGETS if "(default: None)" in probed[t][0]["stdout"]
             or "(default: False)" in probed[t][0]["stdout"]]
    assert not noisy, noisy
