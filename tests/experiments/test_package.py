"""``experiments/`` is a package run from the repository root as ``python -m experiments.<script>``: no file edits
``sys.path`` to find its siblings, and every experiment command of the docs names a module of it whose ``--help``
works."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")),
         *(p for sub in ("experiments", "reports", "tasks", "tutorials")
           for p in sorted((REPO / "docs" / sub).glob("*.md")))]
MODULE_COMMAND = re.compile(r"python[0-9.]*(?: +-[A-Za-z]+)* +-m +experiments\.([A-Za-z0-9_.]+)")
"""``python -m experiments.NAME`` (also ``.venv/bin/python -u -m ...``)."""
PATH_COMMAND = re.compile(r"python[0-9.]*(?: +-[A-Za-z]+)* +(?:\./)?experiments/[^\s/`]+\.py")
"""``python experiments/NAME.py``: runs the file as a script, whose ``from experiments...`` imports then fail."""
SYS_PATH_EDIT = re.compile(r"sys\.path\s*(?:\.\s*(?:insert|append|extend)\s*\(|\+?=|\[)")


def _docs_modules() -> dict[str, list[str]]:
    """{module name after ``experiments.``: the pages that run it}."""
    out: dict[str, list[str]] = {}
    for page in PAGES:
        for name in MODULE_COMMAND.findall(page.read_text(encoding="utf-8")):
            out.setdefault(name.rstrip("."), []).append(page.relative_to(REPO).as_posix())
    return out


def test_the_pattern_tells_the_two_forms_apart():
    text = ("OMP_NUM_THREADS=1 .venv/bin/python -m experiments.verdicts --check; "
            "python -u -m experiments.fig17_simple_task")
    assert MODULE_COMMAND.findall(text) == ["verdicts", "fig17_simple_task"]
    assert not PATH_COMMAND.search(text)
    assert PATH_COMMAND.search("python experiments/verdicts.py --check") and not MODULE_COMMAND.search(
        "python experiments/verdicts.py")
    assert PATH_COMMAND.search("| `python experiments/<script>.py --scale small` |")
    assert SYS_PATH_EDIT.search("sys.path.insert(0, str(REPO))") and SYS_PATH_EDIT.search("sys.path += [x]")
    assert not SYS_PATH_EDIT.search("a path the sys module keeps")


def test_no_experiment_file_edits_sys_path():
    files = [*sorted((REPO / "experiments").rglob("*.py")), *sorted((REPO / "tests" / "experiments").glob("*.py"))]
    this = Path(__file__).resolve()
    assert len(files) > 30
    edits = [f"{f.relative_to(REPO)}:{i}: {line.strip()}" for f in files if f.resolve() != this
             for i, line in enumerate(f.read_text().splitlines(), 1) if SYS_PATH_EDIT.search(line)]
    assert not edits, "run the experiments as `python -m experiments.<script>` instead:\n" + "\n".join(edits)


def test_the_docs_run_experiments_as_modules_that_exist():
    named = _docs_modules()
    assert {"verdicts", "fig17_simple_task", "table14_warm_start_encodings"} <= set(named), sorted(named)
    wrong = [f"{', '.join(sorted(set(pages)))}: python -m experiments.{name}: no experiments/{name}.py"
             for name, pages in named.items() if not (REPO / "experiments" / f"{name}.py").is_file()]
    wrong += [f"{page.relative_to(REPO)}: `{m.group(0)}`: run it as python -m experiments.<script>"
              for page in PAGES for m in PATH_COMMAND.finditer(page.read_text(encoding="utf-8"))]
    assert not wrong, "\n".join(wrong)


def test_the_experiments_the_docs_run_answer_help():
    """Every module the docs name prints its usage under its module name (one interpreter: tests/cli_probe.py)."""
    targets = [f"experiments.{name}" for name in sorted(_docs_modules())]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "COLUMNS": "100"}
    run = subprocess.run([sys.executable, str(REPO / "tests" / "cli_probe.py"),
                          json.dumps({"targets": targets, "argvs": [["--help"]]})],
                         cwd=REPO, capture_output=True, text=True, timeout=300, check=True, env=env)
    probed = json.loads(run.stdout)
    wrong = [f"{t}: status {r['status']}: {(r['stderr'] or r['stdout'])[-300:]}" for t, [r] in probed.items()
             if r["status"] != 0 or not r["stdout"].startswith(f"usage: {t} ")]
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("module", ["experiments.table14_warm_start_encodings"])
def test_a_clone_runs_an_experiment_from_its_root_without_pythonpath(module):
    """What the docs tell a researcher: ``python -m experiments.<script>`` in the clone's root, no PYTHONPATH (the
    package is not installed; the current folder is on the import path under ``-m``)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"OMP_NUM_THREADS": "1", "COLUMNS": "100"}
    run = subprocess.run([sys.executable, "-m", module, "--help"], cwd=REPO, capture_output=True, text=True,
                         timeout=120, check=False, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.startswith(f"usage: {module} ") and "--scale" in run.stdout
