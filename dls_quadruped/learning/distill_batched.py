"""The training seeds of one distillation setting in lockstep: one collection env, one stacked MLP.

Why: an experiment row needs several training seeds; run one after the other they cost K times
the env steps of one run and K times the per-step Python overhead. Here student k of K drives its
own slice of one env's robots (``collect.collect_slots``), keeps its own dataset (one
``DiskDataset`` per seed) and its own observation normaliser, and the K MLPs are one stacked
network trained with one batched matmul per layer (``torch.baddbmm``) and one optimiser.

Same students as K single runs (:class:`DistillTrainer` with ``train.seed`` = k) up to float
rounding: student k is initialised after ``torch.manual_seed(k)``; its mini-batches come from its
own dataset in the order of a generator seeded k; the stacked loss is sum_k MSE_k, whose gradient
with respect to student k's weights is that of MSE_k alone, and Adadelta and the step decay act
element by element, so every student gets its single-run update (``tests/learning/
test_distill_batched.py`` trains both ways on the same data and compares the weights). What differs
is which robots a student collects on: keys ``seed x robots_per_slot + i`` of the collection
schedule, the same for a seed whatever else the env holds.
"""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path

import torch
from torch import nn

from dls_quadruped.learning.collect import SlidingWindows, beta, collect_slots
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_config import DistillConfig
from dls_quadruped.learning.distill_trainer import rows_per_pass
from dls_quadruped.learning.student import Student, encode_labels, metadata

COLLECT_SEED = 3000
"""Schedule seed of the collection env (episodes distinct from the test and SP seeds)."""


class StudentStack(nn.Module):
    """K students' MLPs as one: layer l's weights (K, in, out) and biases (K, 1, out).

    The students keep their normalisers; :meth:`write_back` copies the stacked weights into them
    (for acting, evaluating and saving).
    """

    def __init__(self, students: list[Student]):
        super().__init__()
        self.students = list(students)  # a plain list: not registered, so parameters() is the stack only
        layers = [[m for m in s.mlp if isinstance(m, nn.Linear)] for s in self.students]
        self.weight = nn.ParameterList(nn.Parameter(torch.stack([ls[i].weight.detach().T for ls in layers]).clone())
                                       for i in range(len(layers[0])))
        self.bias = nn.ParameterList(nn.Parameter(torch.stack([ls[i].bias.detach()[None] for ls in layers]).clone())
                                     for i in range(len(layers[0])))
        self.activation = next(m for m in self.students[0].mlp if not isinstance(m, nn.Linear))

    def net(self, obs: torch.Tensor) -> torch.Tensor:
        """(K, B, obs_dim) -> (K, B, D): each student's label-space output on its own batch."""
        x = torch.stack([s.obs_normalizer(obs[k]) for k, s in enumerate(self.students)])
        last = len(self.weight) - 1
        for i, (w, b) in enumerate(zip(self.weight, self.bias)):
            x = torch.baddbmm(b, x, w)  # x W^T + b of nn.Linear, per student
            if i < last:
                x = self.activation(x)
        return x

    @torch.no_grad()
    def write_back(self) -> None:
        for k, s in enumerate(self.students):
            layers = [m for m in s.mlp if isinstance(m, nn.Linear)]
            for i, lin in enumerate(layers):
                lin.weight.copy_(self.weight[i][k].T)
                lin.bias.copy_(self.bias[i][k, 0])


def new_students(seeds: list[int], obs_dim: int, cfg: DistillConfig, hidden_dims, activation: str) -> list[Student]:
    """Student k initialised after ``torch.manual_seed(seeds[k])`` (as ``DistillTrainer`` does)."""
    out = []
    for seed in seeds:
        torch.manual_seed(seed)
        out.append(Student(obs_dim, cfg.encoding.to_encoding(), hidden_dims, activation))
    return out


class SeedGroupTrainer:
    """K seeds of one setting: collect (DAgger per epoch, naive at epoch 0) and train in lockstep.

    Args:
        cfg: the setting (``train.seed`` is ignored; ``seeds`` are used).
        seeds: K training seeds.
        env: ``LocomotionEnv`` with K x ``robots_per_slot`` robots; slot k is seed k's.
        expert: (B, obs_dim) -> (B, 28) raw actions.
        run_dir: ``seed_<s>/dataset`` per seed go there.
        datasets: reuse these (one per seed, e.g. a naive run's expert-driven data) instead of
            collecting; their data must be ``cfg``'s.
    """

    def __init__(self, cfg: DistillConfig, seeds: list[int], env, expert, run_dir: Path, hidden_dims,
                 activation: str, datasets: list[DiskDataset] | None = None, printer=print):
        self.cfg, self.seeds, self.env, self.expert, self.run_dir = cfg, list(seeds), env, expert, Path(run_dir)
        self.print = printer
        self.enc = cfg.encoding.to_encoding()
        self.stride = cfg.encoding.stride(env.step_dt)
        self.obs_dim = int(env.get_observations()["policy"].shape[1])
        if env.num_envs % len(self.seeds):
            raise ValueError(f"{env.num_envs} robots do not split into {len(self.seeds)} slots")
        self.per_slot = env.num_envs // len(self.seeds)
        self.students = new_students(self.seeds, self.obs_dim, cfg, hidden_dims, activation)
        self.stack = StudentStack(self.students)
        self.optimizer = torch.optim.Adadelta(self.stack.parameters(), lr=cfg.train.learning_rate)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=1, gamma=cfg.train.lr_decay)
        self.gens = [torch.Generator().manual_seed(s) for s in self.seeds]
        self.meta = metadata(self.enc, cfg.encoding.dt, self.obs_dim, {"stride": self.stride})
        self.collects = datasets is None
        if datasets is None:
            meta = {k: self.meta[k] for k in ("encoding", "obs_dim", "output_dim")}
            datasets = [DiskDataset.create(self.run_dir / f"seed_{s}" / "dataset", self.obs_dim,
                                           self.meta["output_dim"], cfg.train.dataset_cap, meta) for s in self.seeds]
        else:  # the normaliser follows the data it trains on, as if it had collected it
            for student, ds in zip(self.students, datasets):
                obs, _ = ds.ordered()
                student.obs_normalizer.train()
                student.obs_normalizer.update(obs)
        self.datasets = datasets
        self.epoch = 0
        self.history: list[dict] = []
        self.windows: SlidingWindows | None = None  # carried from epoch to epoch: no warm-up per epoch

    def start(self) -> None:
        """Restart the collection schedule: seed k's robots play keys k x robots_per_slot + i."""
        self.windows = None
        if not self.collects:
            return
        keys = torch.cat([s * self.per_slot + torch.arange(self.per_slot) for s in self.seeds]).to(self.env.device)
        self.env.reset(seed=COLLECT_SEED, episode_keys=keys)

    def _student_actions(self, obs: torch.Tensor) -> torch.Tensor:
        n = self.per_slot
        return torch.cat([s.first_action(obs[k * n:(k + 1) * n]) for k, s in enumerate(self.students)])

    def _collect_epoch(self) -> dict | None:
        cfg = self.cfg
        if not self.collects or (cfg.algorithm == "naive" and self.epoch > 0):
            return None
        if cfg.algorithm == "naive":
            count, b = min(cfg.train.dataset_cap, cfg.train.epochs * cfg.train.datapoints_per_epoch), 1.0
        else:
            count, b = cfg.train.datapoints_per_epoch, beta(cfg.selector, self.epoch)

        def sink(slot: int, obs: torch.Tensor, labels: torch.Tensor) -> None:
            self.datasets[slot].append(obs, labels)
            self.students[slot].obs_normalizer.train()  # the normaliser follows the aggregated data
            self.students[slot].obs_normalizer.update(obs)

        for s in self.students:
            s.eval()
        if self.windows is None:
            obs = self.env.get_observations()["policy"]
            self.windows = SlidingWindows(self.env.num_envs, obs.shape[1], self.env.num_actions, self.enc.horizon,
                                          self.stride, obs.device)
        with torch.no_grad():
            info = collect_slots(self.env, self.expert, [lambda a: encode_labels(a, self.enc)] * len(self.seeds),
                                 count, self.enc.horizon, self.stride, sink, beta_value=b,
                                 student=self._student_actions if b < 1.0 else None, windows=self.windows)
        info["beta"] = b
        return info

    def train_pass(self) -> dict:
        """``passes`` lockstep passes: step j takes mini-batch j of every seed's own shuffled pass."""
        cfg = self.cfg
        sizes = {len(ds) for ds in self.datasets}
        if len(sizes) != 1:
            raise RuntimeError(f"seeds hold datasets of different sizes {sorted(sizes)}; lockstep needs one size")
        limit = rows_per_pass(cfg, self.epoch, sizes.pop())
        losses = torch.zeros(len(self.seeds), dtype=torch.float64)
        steps, t0 = 0, time.monotonic()
        for _ in range(cfg.train.passes):
            passes = [ds.minibatches(cfg.train.batch_size, g, limit=limit) for ds, g in zip(self.datasets, self.gens)]
            for batches in zip(*passes):
                obs = torch.stack([b[0] for b in batches])
                labels = torch.stack([b[1] for b in batches])
                loss = (self.stack.net(obs) - labels).square().mean(dim=(1, 2))  # (K,) each seed's MSE
                self.optimizer.zero_grad(set_to_none=True)
                loss.sum().backward()  # d(sum_k MSE_k)/d(theta_k) = d MSE_k / d theta_k
                self.optimizer.step()
                losses += loss.detach().double()
                steps += 1
        self.scheduler.step()
        self.stack.write_back()
        seconds = time.monotonic() - t0
        return {"loss": (losses / max(steps, 1)).tolist(), "steps": steps, "seconds": seconds,
                "steps_per_s": steps / max(seconds, 1e-9)}

    def run_epoch(self) -> dict:
        t0 = time.monotonic()
        collected = self._collect_epoch()
        trained = self.train_pass()
        for s in self.students:
            s.eval()
        row = {"epoch": self.epoch + 1, "beta": None if collected is None else collected["beta"],
               "collect": collected, "train": trained, "train_loss": trained["loss"],
               "lr": self.scheduler.get_last_lr()[0], "dataset_size": len(self.datasets[0]),
               "seconds": time.monotonic() - t0}
        self.history.append(row)
        self.epoch += 1
        return row

    def state_dicts(self) -> list[dict]:
        return [copy.deepcopy(s.state_dict()) for s in self.students]


def gradient_steps(cfg: DistillConfig) -> int:
    """Gradient steps of a whole run (one seed): sum over epochs of ceil(rows / batch) x passes."""
    t = cfg.train
    total = 0
    for i in range(t.epochs):
        size = min(t.dataset_cap, (t.epochs if cfg.algorithm == "naive" else i + 1) * t.datapoints_per_epoch)
        rows = rows_per_pass(cfg, i, size) or size
        total += t.passes * math.ceil(rows / t.batch_size)
    return total
