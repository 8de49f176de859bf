"""Building and closing a CPU env with a worker process leaves at most the two shared-memory segments of its
buffers (``sim/buffers.py``) open until the garbage collector frees the env's reference cycles, and nothing after:
a long run that builds envs again and again keeps its open files flat. Before the buffers were views of two blocks,
each of the 24 buffers held its own descriptor until ``gc.collect()``."""

from __future__ import annotations

import gc
import os

import pytest

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="counts /proc/self/fd (Linux)")


def _open() -> int:
    return len(os.listdir("/proc/self/fd"))


def _cycle() -> None:
    env = LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 1}}), num_envs=2, verbose=False)
    env.reset()
    env.close()


def test_env_close_cycles_keep_open_files_flat():
    _cycle()  # the first one opens what stays for the process (multiprocessing's resource tracker)
    gc.collect()
    before = _open()
    left = []
    for _ in range(3):
        _cycle()
        left.append(_open() - before)  # before the collector: the buffers' two segments at most
        gc.collect()
        assert _open() == before
    assert max(left) <= 2, left
