"""The training seeds of one distillation setting in lockstep: one collection env, one stacked MLP
(several settings too, when they differ only in the encoding's p and F).

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
    """S students' MLPs as one: layer l's weights (S, in, out) and biases (S, 1, out).

    Students of different output sizes D_s (encodings) are stacked with their last layer padded to
    the largest D with zero columns; ``mask`` (S, 1, D) marks each student's own outputs, and a loss
    that ignores the padding gives those columns zero gradient, so they stay zero (Adadelta's step
    is proportional to the gradient). The students keep their normalisers; :meth:`write_back`
    copies the stacked weights into them (for acting, evaluating and saving).
    """

    def __init__(self, students: list[Student]):
        super().__init__()
        self.students = list(students)  # a plain list: not registered, so parameters() is the stack only
        layers = [[m for m in s.mlp if isinstance(m, nn.Linear)] for s in self.students]
        self.dims = [ls[-1].out_features for ls in layers]
        d_max = max(self.dims)

        def pad(t: torch.Tensor) -> torch.Tensor:  # (..., D_s) -> (..., D_max), zeros appended
            return nn.functional.pad(t, (0, d_max - t.shape[-1]))

        n = len(layers[0])
        self.weight = nn.ParameterList(nn.Parameter(torch.stack(
            [(pad(ls[i].weight.detach().T) if i == n - 1 else ls[i].weight.detach().T) for ls in layers]).clone())
            for i in range(n))
        self.bias = nn.ParameterList(nn.Parameter(torch.stack(
            [(pad(ls[i].bias.detach()) if i == n - 1 else ls[i].bias.detach())[None] for ls in layers]).clone())
            for i in range(n))
        self.register_buffer("mask", (torch.arange(d_max)[None] < torch.tensor(self.dims)[:, None]).float()[:, None])
        self.activation = next(m for m in self.students[0].mlp if not isinstance(m, nn.Linear))

    def net(self, obs: torch.Tensor) -> torch.Tensor:
        """(S, B, obs_dim) -> (S, B, D_max): each student's label-space output on its own batch
        (zeros beyond its D_s)."""
        x = torch.stack([s.obs_normalizer(obs[k]) for k, s in enumerate(self.students)])
        last = len(self.weight) - 1
        for i, (w, b) in enumerate(zip(self.weight, self.bias)):
            x = torch.baddbmm(b, x, w)  # x W^T + b of nn.Linear, per student
            if i < last:
                x = self.activation(x)
        return x

    def mse(self, obs: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """(S,) each student's mean squared error over its batch and its own D_s outputs.

        Args:
            obs: (S, B, obs_dim); labels: (S, B, D_max), padded with anything beyond D_s.
        """
        sq = (self.net(obs) - labels).square() * self.mask
        return sq.sum(dim=(1, 2)) / (obs.shape[1] * torch.tensor(self.dims, dtype=sq.dtype))

    @torch.no_grad()
    def write_back(self) -> None:
        for k, s in enumerate(self.students):
            layers = [m for m in s.mlp if isinstance(m, nn.Linear)]
            for i, lin in enumerate(layers):
                lin.weight.copy_(self.weight[i][k, :, :lin.out_features].T)
                lin.bias.copy_(self.bias[i][k, 0, :lin.out_features])


def new_students(seeds: list[int], obs_dim: int, cfg: DistillConfig, hidden_dims, activation: str) -> list[Student]:
    """Student k initialised after ``torch.manual_seed(seeds[k])`` (as ``DistillTrainer`` does)."""
    out = []
    for seed in seeds:
        torch.manual_seed(seed)
        out.append(Student(obs_dim, cfg.encoding.to_encoding(), hidden_dims, activation))
    return out


def check_lockstep(cfgs: list[DistillConfig]) -> None:
    """Settings trained together must share everything but the encoding's p and F.

    Raises:
        ValueError: naming the first field that differs.
    """
    ref = cfgs[0].to_dict()
    for c in cfgs[1:]:
        d = c.to_dict()
        for key in ("algorithm", "selector", "train"):
            if d[key] != ref[key]:
                raise ValueError(f"settings trained together differ in {key}: {ref[key]} vs {d[key]}")
        for key in ("horizon", "dt"):
            if d["encoding"][key] != ref["encoding"][key]:
                raise ValueError(f"settings trained together differ in encoding.{key}")


class SeedGroupTrainer:
    """Every seed of one or more settings: collect (DAgger per epoch, naive at epoch 0) and train in lockstep.

    Args:
        cfg: the setting, or M settings differing only in the encoding's p and F
            (:func:`check_lockstep`); ``train.seed`` is ignored, ``seeds`` are used.
        seeds: K training seeds.
        env: ``LocomotionEnv`` with M x K x ``robots_per_slot`` robots; slot m K + k is setting m's seed k.
        expert: (B, obs_dim) -> (B, 28) raw actions.
        run_dir: one per setting; ``seed_<s>/dataset`` per seed go there.
        datasets: reuse these (one per slot, e.g. a naive run's expert-driven data) instead of
            collecting; their data must be the settings'.
    """

    def __init__(self, cfg: DistillConfig | list[DistillConfig], seeds: list[int], env, expert,
                 run_dir: Path | list[Path], hidden_dims, activation: str, datasets: list[DiskDataset] | None = None,
                 printer=print):
        self.cfgs = list(cfg) if isinstance(cfg, list) else [cfg]
        run_dirs = [Path(d) for d in run_dir] if isinstance(run_dir, list) else [Path(run_dir)]
        check_lockstep(self.cfgs)
        self.cfg, self.seeds, self.env, self.expert = self.cfgs[0], list(seeds), env, expert
        self.print = printer
        self.slots = [(m, s) for m in range(len(self.cfgs)) for s in self.seeds]
        self.encs = [c.encoding.to_encoding() for c in self.cfgs]
        self.horizon = self.encs[0].horizon
        self.stride = self.cfg.encoding.stride(env.step_dt)
        self.obs_dim = int(env.get_observations()["policy"].shape[1])
        if env.num_envs % len(self.slots):
            raise ValueError(f"{env.num_envs} robots do not split into {len(self.slots)} slots")
        self.per_slot = env.num_envs // len(self.slots)
        self.students = [new_students([s], self.obs_dim, self.cfgs[m], hidden_dims, activation)[0]
                         for m, s in self.slots]
        self.stack = StudentStack(self.students)
        self.optimizer = torch.optim.Adadelta(self.stack.parameters(), lr=self.cfg.train.learning_rate)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=1, gamma=self.cfg.train.lr_decay)
        self.gens = [torch.Generator().manual_seed(s) for _, s in self.slots]
        self.metas = [metadata(e, c.encoding.dt, self.obs_dim, {"stride": self.stride})
                      for e, c in zip(self.encs, self.cfgs)]
        self.collects = datasets is None
        if datasets is None:
            datasets = []
            for m, s in self.slots:
                meta = {k: self.metas[m][k] for k in ("encoding", "obs_dim", "output_dim")}
                datasets.append(DiskDataset.create(run_dirs[m] / f"seed_{s}" / "dataset", self.obs_dim,
                                                   self.metas[m]["output_dim"], self.cfg.train.dataset_cap, meta))
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
        """Restart the collection schedule: seed k's robots play keys k x robots_per_slot + i (in every
        setting: the settings of one seed see the same collection episodes)."""
        self.windows = None
        if not self.collects:
            return
        keys = torch.cat([s * self.per_slot + torch.arange(self.per_slot) for _, s in self.slots])
        self.env.reset(seed=COLLECT_SEED, episode_keys=keys.to(self.env.device))

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
            self.windows = SlidingWindows(self.env.num_envs, obs.shape[1], self.env.num_actions, self.horizon,
                                          self.stride, obs.device)
        encoders = [(lambda a, e=self.encs[m]: encode_labels(a, e)) for m, _ in self.slots]
        with torch.no_grad():
            info = collect_slots(self.env, self.expert, encoders, count, self.horizon, self.stride, sink,
                                 beta_value=b, student=self._student_actions if b < 1.0 else None,
                                 windows=self.windows)
        info["beta"] = b
        return info

    def train_pass(self) -> dict:
        """``passes`` lockstep passes: step j takes mini-batch j of every slot's own shuffled pass."""
        cfg = self.cfg
        sizes = {len(ds) for ds in self.datasets}
        if len(sizes) != 1:
            raise RuntimeError(f"slots hold datasets of different sizes {sorted(sizes)}; lockstep needs one size")
        limit = rows_per_pass(cfg, self.epoch, sizes.pop())
        d_max = max(self.stack.dims)
        losses = torch.zeros(len(self.slots), dtype=torch.float64)
        steps, t0 = 0, time.monotonic()
        for _ in range(cfg.train.passes):
            passes = [ds.minibatches(cfg.train.batch_size, g, limit=limit) for ds, g in zip(self.datasets, self.gens)]
            for batches in zip(*passes):
                obs = torch.stack([b[0] for b in batches])
                labels = torch.stack([nn.functional.pad(b[1], (0, d_max - b[1].shape[1])) for b in batches])
                loss = self.stack.mse(obs, labels)  # (S,) each slot's MSE
                self.optimizer.zero_grad(set_to_none=True)
                loss.sum().backward()  # d(sum_s MSE_s)/d(theta_s) = d MSE_s / d theta_s
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

    def member_history(self, m: int) -> list[dict]:
        """Setting m's view of the history: its seeds' train losses and datapoints."""
        idx = [i for i, (mm, _) in enumerate(self.slots) if mm == m]
        out = []
        for row in self.history:
            r = dict(row, train_loss=[row["train_loss"][i] for i in idx])
            if row["collect"] is not None:
                r["collect"] = dict(row["collect"], datapoints=[row["collect"]["datapoints"][i] for i in idx])
            out.append(r)
        return out

    def state_dicts(self, m: int = 0) -> list[dict]:
        """Setting m's students (one per seed)."""
        return [copy.deepcopy(s.state_dict()) for s, (mm, _) in zip(self.students, self.slots) if mm == m]


def gradient_steps(cfg: DistillConfig) -> int:
    """Gradient steps of a whole run (one seed): sum over epochs of ceil(rows / batch) x passes."""
    t = cfg.train
    total = 0
    for i in range(t.epochs):
        size = min(t.dataset_cap, (t.epochs if cfg.algorithm == "naive" else i + 1) * t.datapoints_per_epoch)
        rows = rows_per_pass(cfg, i, size) or size
        total += t.passes * math.ceil(rows / t.batch_size)
    return total
