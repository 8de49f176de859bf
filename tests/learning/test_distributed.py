"""torchrun with two CPU processes (gloo): both ranks end with the same weights, rank 0 alone writes.

``learning/distributed.py`` and ``AtomicOnPolicyRunner._configure_multi_gpu`` replace rsl-rl-lib's
NCCL-only process group; this launches the real ``train.main`` under torchrun (through
``dist_worker.py``, which only adds a dump of each rank's state) for 2 iterations on 4 robots per rank.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from dls_quadruped.learning.distributed import Ranks, backend_for, ranks_from_env

WORKER = Path(__file__).with_name("dist_worker.py")


def test_ranks_and_backend_from_torchrun_variables():
    assert ranks_from_env({}) == Ranks(1, 0, 0) and not Ranks().is_distributed
    ranks = ranks_from_env({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"})
    assert ranks == Ranks(4, 3, 1) and ranks.is_distributed and not ranks.is_main
    with pytest.raises(ValueError, match="out of range"):
        ranks_from_env({"WORLD_SIZE": "2", "RANK": "2"})
    assert backend_for("cpu", ranks) == "gloo"
    assert backend_for("cuda:1", ranks) == "nccl"
    with pytest.raises(ValueError, match="expected 'cuda:1'"):  # one GPU per process, the local rank's
        backend_for("cuda:0", ranks)
    with pytest.raises(ValueError, match="'cpu' \\(gloo\\) or 'cuda' \\(nccl\\)"):
        backend_for("mps", ranks)


def _tensors(state: dict) -> dict[str, torch.Tensor]:
    """Every tensor of an ``alg.save()`` dict (networks incl. normalisers, Adam moments), by dotted name."""
    out = {}

    def walk(prefix, value):
        if isinstance(value, torch.Tensor):
            out[prefix] = value
        elif isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}", v)
        elif isinstance(value, (list, tuple)):
            for k, v in enumerate(value):
                walk(f"{prefix}.{k}", v)

    walk("", state)
    return out


@pytest.mark.slow  # two torchrun launches of two processes each: 20-45 s on 2 shared cores
def test_torchrun_two_cpu_ranks_end_with_identical_weights(tmp_path):
    dump, run_dir = tmp_path / "dump", tmp_path / "runs" / "dist"
    dump.mkdir()
    env = {**os.environ, "DLS_RANK_DUMP_DIR": str(dump), "OMP_NUM_THREADS": "1"}
    torchrun = Path(sys.executable).with_name("torchrun")
    cmd = [str(torchrun), "--standalone", "--nproc_per_node=2", str(WORKER), "--task", "base",
           "--num-envs", "4", "--iterations", "2", "--num-workers", "0", "--device", "cpu",
           "--run-dir", str(run_dir), "--save-interval", "1"]
    proc = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    r0, r1 = (torch.load(dump / f"rank{r}.pt", weights_only=False) for r in (0, 1))
    assert r0["backend"] == r1["backend"] == "gloo" and r0["world_size"] == r1["world_size"] == 2
    # the ranks started from different random weights (seed + rank) and simulated different rollouts...
    w0, w1 = _tensors(r0["before"]["actor_state_dict"]), _tensors(r1["before"]["actor_state_dict"])
    assert not torch.equal(w0[".mlp.0.weight"], w1[".mlp.0.weight"])
    assert not torch.equal(r0["last_rollout_rewards"], r1["last_rollout_rewards"])
    # ...and still end bit-identical: rank 0's weights broadcast, gradients, KL and normaliser all-reduced
    a0, a1 = _tensors(r0["after"]), _tensors(r1["after"])
    assert a0.keys() == a1.keys() and any(".optimizer_state_dict.state." in k for k in a0)
    diverged = [k for k in a0 if not torch.equal(a0[k], a1[k])]
    assert not diverged, f"parameters differ between ranks: {diverged[:5]}"
    assert r0["learning_rate"] == r1["learning_rate"]
    moved = _tensors(r0["before"]["actor_state_dict"])
    assert not torch.equal(moved[".mlp.0.weight"], a0[".actor_state_dict.mlp.0.weight"])  # it trained

    # one run directory, written by rank 0 alone: its checkpoint is rank 0's final state
    assert [p.name for p in run_dir.parent.iterdir()] == ["dist"]
    assert len(list(run_dir.glob("events.out.tfevents.*"))) == 1
    assert sorted(p.name for p in run_dir.glob("model_*.pt")) == ["model_0.pt", "model_1.pt"]
    ckpt = _tensors(torch.load(run_dir / "model_1.pt", weights_only=False)["actor_state_dict"])
    assert all(torch.equal(v, a1[f".actor_state_dict{k}"]) for k, v in ckpt.items())
    assert (run_dir / "exported" / "policy.pt2").is_file() and (run_dir / "task.yaml").is_file()

    # a second launch onto the same, now non-empty, --run-dir: the ranks refuse with one line each, nothing in the
    # directory changes, and no rank is left waiting for the others (the timeout). torchrun stops the other rank as
    # soon as one fails, so whether the slower rank got to print its line is a race: one or two lines
    before = sorted((p.name, p.stat().st_mtime_ns) for p in run_dir.rglob("*"))
    proc = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    refusals = [line for line in (proc.stdout + proc.stderr).splitlines() if "is not empty; add --resume" in line]
    assert len(refusals) in (1, 2), refusals
    assert all(line.startswith("dist_worker.py: error: --run-dir") for line in refusals), refusals
    assert sorted((p.name, p.stat().st_mtime_ns) for p in run_dir.rglob("*")) == before
