"""bench.device (issue 26 item 6) on the CPU at tiny sizes: every section is written, the solve includes its kernel,
a bad backend is a one-line usage error, and only an out-of-memory error ends a task's sizes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from dls_quadruped.bench import device as D


def test_device_bench_writes_env_mpc_and_closed_loop_rows(tmp_path: Path) -> None:
    D.main(["--device", "cpu", "--backend", "cpu", "--tasks", "base", "--sizes", "4", "--steps", "2", "--warmup", "1",
            "--samples", "300", "--solves", "2", "--closed-loop-robots", "2", "--closed-loop-seconds", "0.1",
            "--out", str(tmp_path)])
    res = json.loads((tmp_path / "device.json").read_text())
    assert res["backend"] == "cpu" and res["kernel"] == "cpp" and res["machine"]["device"] == "cpu"
    (env,) = res["env"]
    assert env["task"] == "base" and env["num_envs"] == 4 and env["steps_per_s"] > 0
    assert env["steps_per_s"] == pytest.approx(4 * 2 / env["wall_s"])
    assert isinstance(env["resets"], int) and 0 <= env["resets"] <= 4 * 2
    (mpc,) = res["mpc"]
    assert mpc["samples"] == 300 and 0 < mpc["kernel_s"] <= mpc["solve_s"]
    (loop,) = res["closed_loop"]
    assert loop["robots"] == 2 and loop["robot_seconds_per_second"] > 0 and 0 < loop["kernel_share"] < 1


def test_the_closed_loop_rows_alone(tmp_path: Path) -> None:
    """``--tasks`` and ``--samples`` given no value skip the env and solve rows (the GPU lease's ``loop``)."""
    D.main(["--device", "cpu", "--backend", "cpu", "--tasks", "--samples", "--closed-loop-robots", "2",
            "--closed-loop-seconds", "0.1", "--closed-loop-samples", "300", "--out", str(tmp_path)])
    res = json.loads((tmp_path / "device.json").read_text())
    assert res["env"] == [] and res["mpc"] == []
    (loop,) = res["closed_loop"]
    assert loop["robots"] == 2 and loop["samples"] == 300 and loop["robot_seconds_per_second"] > 0


def test_unknown_backend_is_a_usage_error(capsys) -> None:
    with pytest.raises(SystemExit) as err:
        D.main(["--device", "cpu", "--backend", "warp-typo", "--out", "/nonexistent"])
    assert err.value.code == 2
    assert "unknown simulator backend 'warp-typo'" in capsys.readouterr().err


def test_only_out_of_memory_ends_a_tasks_sizes() -> None:
    assert D._out_of_memory(torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"))
    assert D._out_of_memory(RuntimeError("Warp CUDA error: out of memory"))
    assert not D._out_of_memory(ValueError("num_envs must be >= 1"))


def test_warps_failed_allocation_is_out_of_memory_but_a_capture_without_pools_is_not() -> None:
    # the messages of warp/_src/context.py's allocators (Warp 1.19)
    assert D._out_of_memory(RuntimeError("Failed to allocate 17179869184 bytes on device 'cuda:0'"))
    assert not D._out_of_memory(RuntimeError("Failed to allocate memory during graph capture because memory pools "
                                             "are not enabled on device 'cuda:0'"))
