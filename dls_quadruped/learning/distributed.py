"""torchrun process group for training: gloo on CPU, NCCL on GPUs.

rsl-rl-lib 5.x joins the process group itself, with NCCL only (``OnPolicyRunner._configure_multi_gpu``),
so ``torchrun`` could not run on a CPU machine. ``init_distributed`` joins it with the backend that
fits ``--device``; ``train.py`` calls it before it builds anything (rank 0 chooses the run directory
and tells the others) and ``AtomicOnPolicyRunner`` reuses the group it made.

torchrun sets ``WORLD_SIZE`` (processes), ``RANK`` (this process among all) and ``LOCAL_RANK`` (this
process on its machine, = its GPU); without them the run is a single process and nothing here
touches ``torch.distributed``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class Ranks:
    """Where this process stands in a torchrun launch (world_size 1: no launch)."""

    world_size: int = 1
    rank: int = 0
    local_rank: int = 0

    @property
    def is_distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the only process that writes the run directory (configs, logs, checkpoints, exports)."""
        return self.rank == 0


def ranks_from_env(environ: dict | None = None) -> Ranks:
    """``Ranks`` from torchrun's ``WORLD_SIZE``/``RANK``/``LOCAL_RANK`` (defaults 1/0/0).

    Raises:
        ValueError: a rank outside ``[0, WORLD_SIZE)``.
    """
    env = os.environ if environ is None else environ
    ranks = Ranks(int(env.get("WORLD_SIZE", "1")), int(env.get("RANK", "0")), int(env.get("LOCAL_RANK", "0")))
    if ranks.world_size < 1 or not 0 <= ranks.rank < ranks.world_size or not 0 <= ranks.local_rank < ranks.world_size:
        raise ValueError(f"torchrun ranks out of range: {ranks}")
    return ranks


def backend_for(device: str, ranks: Ranks) -> str:
    """``"gloo"`` for ``cpu``; ``"nccl"`` for ``cuda:<LOCAL_RANK>`` (one GPU per process).

    Raises:
        ValueError: another device, or a GPU that is not this process's ``cuda:<LOCAL_RANK>``
            (two processes on one GPU would serialise and share its memory).
    """
    if device == "cpu":
        return "gloo"
    if device.startswith("cuda"):
        if device != f"cuda:{ranks.local_rank}":
            raise ValueError(f"device {device!r} under torchrun: expected 'cuda:{ranks.local_rank}' "
                             f"(LOCAL_RANK); pass --device cuda")
        return "nccl"
    raise ValueError(f"device {device!r}: distributed training runs on 'cpu' (gloo) or 'cuda' (nccl)")


def init_distributed(device: str) -> Ranks:
    """Join torchrun's process group once (later calls return the same ranks); no-op for a single process."""
    ranks = ranks_from_env()
    if not ranks.is_distributed or dist.is_initialized():
        return ranks
    backend = backend_for(device, ranks)
    if backend == "nccl":
        torch.cuda.set_device(ranks.local_rank)
    dist.init_process_group(backend=backend, rank=ranks.rank, world_size=ranks.world_size)
    return ranks


def close_distributed() -> None:
    """Leave the process group (NCCL warns at exit otherwise)."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def broadcast_from_main(value, ranks: Ranks):
    """Rank 0's ``value`` (any picklable object) on every rank; ``value`` itself for a single process."""
    if not ranks.is_distributed:
        return value
    box = [value if ranks.is_main else None]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def any_rank(flag: int, ranks: Ranks, device: str) -> int:
    """Max of ``flag`` over the ranks: one rank's stop request stops them all at the same iteration
    (a rank that stopped alone would leave the others waiting in the next gradient all-reduce)."""
    if not ranks.is_distributed:
        return flag
    t = torch.tensor([flag], dtype=torch.int64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return int(t.item())
