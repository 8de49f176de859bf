"""Backend faults: dead, stopped and interrupted workers; scripts without a ``__main__`` guard."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import mujoco
import pytest

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim, WorkerError
from dls_quadruped.sim.cpu_workers import _inside_main_guard

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))


def test_killed_worker_is_named_with_its_exit_code(model):
    with VecSim(model, 4, SimConfig(num_workers=2)) as sim:
        sim.step(1)
        victim = sim.workers.procs[1]
        os.kill(victim.pid, signal.SIGKILL)
        victim.join(timeout=10)
        start = time.monotonic()
        with pytest.raises(WorkerError, match=rf"simulator worker 1 \(pid {victim.pid}\) died with exit code -9 "
                                              r"during step \(killed by SIGKILL\)"):
            sim.step(1)
        assert time.monotonic() - start < 10.0
        with pytest.raises(WorkerError, match="worker 1"):  # every later call says the same, never hangs
            sim.step(1)


def test_stopped_worker_times_out_and_close_kills_it(model):
    sim = VecSim(model, 4, SimConfig(num_workers=2, reply_timeout_s=1.5))
    victim = sim.workers.procs[0]
    try:
        os.kill(victim.pid, signal.SIGSTOP)
        start = time.monotonic()
        with pytest.raises(WorkerError, match=r"simulator worker 0 \(pid \d+\) gave no answer within 1.5 s "
                                              r"during step \(process state: T \(stopped\)\)"):
            sim.step(1)
        assert time.monotonic() - start < 6.0
    finally:
        sim.close()
    victim.join(timeout=10)
    assert not victim.is_alive()


def test_workers_ignore_ctrl_c_so_the_trainer_can_save(model):
    with VecSim(model, 2, SimConfig(num_workers=2)) as sim:
        for proc in sim.workers.procs:
            os.kill(proc.pid, signal.SIGINT)
            os.kill(proc.pid, signal.SIGTERM)
        time.sleep(0.5)
        sim.step(2)
        assert all(p.is_alive() for p in sim.workers.procs)


def test_main_guard_detection_reads_the_script(tmp_path):
    script = tmp_path / "s.py"
    script.write_text(textwrap.dedent("""\
        import x
        build()
        if __name__ == "__main__":
            build()
            other()
        if "__main__" == __name__:
            build()
        if __name__ == "x":
            build()
    """))
    assert [_inside_main_guard(str(script), line) for line in range(1, 10)] == [
        False, False, False, True, True, False, True, False, False]


SCRIPT = """\
import mujoco, torch
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim

def go():
    with VecSim(mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 2, SimConfig(num_workers=1)) as sim:
        sim.step(1)
    print("stepped")
"""


@pytest.mark.parametrize("guarded", [False, True])
def test_script_without_main_guard_is_explained_not_hung(guarded, tmp_path):
    script = tmp_path / "user_script.py"
    script.write_text(SCRIPT + ('if __name__ == "__main__":\n    go()\n' if guarded else "go()\n"))
    out = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=240,
                         check=False)
    if guarded:
        assert out.returncode == 0 and "stepped" in out.stdout, out.stderr[-2000:]
    else:
        assert out.returncode != 0
        assert f"{script}:" in out.stderr and 'without an `if __name__ == "__main__":` guard' in out.stderr


def test_workers_exit_when_their_parent_is_killed(tmp_path):
    script = tmp_path / "parent.py"
    script.write_text(SCRIPT.replace('        sim.step(1)\n', '        sim.step(1)\n'
                                     '        print(*[p.pid for p in sim.workers.procs], flush=True)\n'
                                     '        import time; time.sleep(600)\n')
                      .replace("SimConfig(num_workers=1)", "SimConfig(num_workers=2)")
                      + 'if __name__ == "__main__":\n    go()\n')
    parent = subprocess.Popen([sys.executable, str(script)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2
    finally:
        parent.kill()
        parent.wait(timeout=30)
    deadline = time.monotonic() + 20.0
    alive = pids
    while alive and time.monotonic() < deadline:
        time.sleep(0.2)
        alive = [pid for pid in pids if _running(pid)]
    assert not alive, f"workers {alive} outlived their parent"


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
