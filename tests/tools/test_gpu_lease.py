"""``tools/gpu_lease.sh`` dry-run on the CPU (``LEASE_DEVICE=cpu``: every section on Warp's CPU device, backend
``warp-cpu``, at tiny sizes): the commands a GPU lease runs, run here first, so a wrong flag or a broken hand-over
between sections does not cost a lease's minutes. Needs the ``[gpu]`` extra (``make test-gpu-path``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_every_section_of_a_lease_runs_on_the_cpu_and_brings_its_results_back(tmp_path):
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    out, site = tmp_path / "out", tmp_path / "site"
    out.mkdir()
    (site / "warp").mkdir(parents=True)  # the wheels count as unpacked: this machine has them installed
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}", "OMP_NUM_THREADS": "1",
           "OUT": str(out), "SITE": str(site), "CACHES": str(tmp_path / "caches"), "PACK": str(tmp_path / "pack"),
           "LEASE_DEVICE": "cpu", "LEASE_S": "900", "SECTIONS": "mpc scaling check loop train",
           "MPC_S": "60", "MPC_ARGS": "--samples 200 --robots 1 2 --solves 2 --point-s 0.2",
           "SCALING_S": "60", "SCALING_ARGS": "--samples 200 --robots 1 --threads 1 --solves 2 --point-s 0.2",
           "CHECK_S": "150", "CHECK_ARGS": "--skip compile,trajectories,syncs,launches,faults,env,gpu_busy,mpc,rough,"
                                           "train",
           "LOOP_B": "2", "LOOP_ARGS": "--closed-loop-seconds 0.1 --closed-loop-samples 200",
           "TRAIN_ENVS": "4", "TRAIN_S": "40"}
    run = subprocess.run(["bash", str(REPO / "dls_quadruped/tools/gpu_lease.sh")], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=900, check=False)
    log = run.stdout + run.stderr
    assert run.returncode == 0, log[-3000:]
    for section in ("mpc", "scaling", "loop", "train"):
        assert f"{section}: rc 0 after" in log, log[-3000:]
    assert "Traceback" not in log, log[-3000:]
    with tarfile.open(out / "results.tar") as tar:
        files = {Path(n).name: tar.extractfile(n) for n in tar.getnames() if tar.getmember(n).isfile()}
        mpc = json.loads(files["mpc_warp.json"].read())
        check = json.loads(files["gpu_check.json"].read())
        loop = json.loads(files["closed_loop_cpu.json"].read())
        curve = files["learning_curve.csv"].read().decode()
        assert {"mpc_scaling_cpu.json", "base_gpu_actor.pt2", "cache_sizes.txt", "machine.txt"} <= set(files)
    assert mpc["results"] and all("error" not in r for r in mpc["results"]), mpc["results"]
    assert check["backend"] == "warp-cpu" and "versions" in check["sections"]
    graph = check["sections"]["graph"]
    assert "error" not in graph and "skipped" not in graph and graph["agreement"], graph
    (row,) = loop["closed_loop"]
    assert row["robots"] == 2 and row["robot_seconds_per_second"] > 0
    assert len(curve.splitlines()) >= 2
    start = torch.load(REPO / "docs/policies/gpu/base_h200_resume.pt", map_location="cpu", weights_only=False)
    end = torch.load(out / "base_gpu_resume.pt", map_location="cpu", weights_only=False)
    assert end["iter"] > start["iter"] and "episodes" not in end["env_state"]
    assert list(out.glob("gpu_caches.tar.xz.part*"))
