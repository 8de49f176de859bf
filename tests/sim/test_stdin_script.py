"""A script read from standard input (``python - <<EOF``) cannot be re-imported by spawned simulator workers: it
is refused at once with the advice a script without a ``__main__`` guard gets, and runs without workers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

SCRIPT = """\
import mujoco
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim

if __name__ == "__main__":  # guarded, and still not re-importable from <stdin>
    with VecSim(mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 2, SimConfig(num_workers={workers})) as sim:
        sim.step(1)
    print("stepped")
"""


@pytest.mark.parametrize("workers", [1, 0])
def test_script_on_stdin_is_refused_with_workers_and_runs_without(workers):
    # the timeout is the test's own guard: before the check, the parent blocked for ever starting the worker
    out = subprocess.run([sys.executable, "-"], input=SCRIPT.format(workers=workers), cwd=REPO, capture_output=True,
                         text=True, timeout=120, check=False)
    if workers == 0:
        assert out.returncode == 0 and "stepped" in out.stdout, out.stderr[-2000:]
        return
    assert out.returncode != 0 and "stepped" not in out.stdout
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("dls_quadruped.sim.cpu_workers.WorkerError: <stdin> starts simulator worker processes "
                           "from a script that is not a file"), out.stderr[-2000:]
    assert 'under an `if __name__ == "__main__":` guard (see docs/env.md) or use num_workers=0' in last
    assert "FileNotFoundError" not in out.stderr  # no worker was started
