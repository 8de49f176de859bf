"""torchrun worker for ``test_distributed.py``: ``train.main`` unchanged, plus a dump of this rank's
networks, optimiser and learning rate before and after ``learn`` (and its last rollout's rewards) into
``$DLS_RANK_DUMP_DIR/rank<r>.pt``
(rank 1 saves nothing of its own, so this is the only way to see its weights)."""

from __future__ import annotations

import copy
import os
import sys
from pathlib import Path

from dls_quadruped.cli import run_cli
from dls_quadruped.learning import train
from dls_quadruped.learning.runner import AtomicOnPolicyRunner

_learn = AtomicOnPolicyRunner.learn


def _learn_and_dump(self, *args, **kwargs):
    before = copy.deepcopy(self.alg.save())  # after construction, before rsl-rl broadcasts rank 0's weights
    _learn(self, *args, **kwargs)
    import torch

    torch.save({"before": before, "after": self.alg.save(), "learning_rate": self.alg.learning_rate,
                "last_rollout_rewards": self.alg.storage.rewards.clone(),
                "world_size": self.gpu_world_size, "backend": torch.distributed.get_backend()},
               Path(os.environ["DLS_RANK_DUMP_DIR"]) / f"rank{os.environ['RANK']}.pt")


AtomicOnPolicyRunner.learn = _learn_and_dump

if __name__ == "__main__":
    run_cli(train.main, sys.argv[1:])
