"""Closing after a worker died: the surviving worker ends quietly (no BrokenPipeError traceback)."""

from __future__ import annotations

import os
import signal

import mujoco
import pytest

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim, WorkerError


def test_surviving_worker_ends_without_a_traceback_after_another_died(capfd):
    sim = VecSim(mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 4, SimConfig(num_workers=2))
    survivor, victim = sim.workers.procs
    sim.step(1)
    os.kill(victim.pid, signal.SIGKILL)  # the last worker: the step reaches worker 0 first, its answer stays unread
    victim.join(timeout=10)
    with pytest.raises(WorkerError, match="simulator worker 1"):
        sim.step(1)
    sim.close()  # reads worker 0's stale step answer, hangs up before its answer to "close"
    survivor.join(timeout=10)
    assert survivor.exitcode == 0
    err = capfd.readouterr().err  # the workers write to the inherited stderr
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
