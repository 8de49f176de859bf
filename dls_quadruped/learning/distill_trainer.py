"""One trainer, two modes: naive imitation (Algorithm 3) and DAgger with the modified action space
(Algorithm 4).

Why not rsl-rl-lib's ``Distillation``/``DistillationRunner``: they label each state with the
teacher's *current* action and keep no dataset, so they cannot express horizon labels, the beta
mixing of the applied action or an aggregated, capped dataset. Reused from rsl-rl-lib: the MLP
and observation normaliser (``student.Student``). TensorBoard scalars go through
``torch.utils.tensorboard`` (rsl-rl's ``Logger`` is tied to its PPO rollout storage).

Per epoch i (0-based):

* dagger: collect ``datapoints_per_epoch`` with beta(i) = selector(i) (epoch 0: beta = 1, the
  expert drives), append to the dataset (FIFO at the cap);
* naive: at epoch 0 only, collect min(cap, epochs x datapoints_per_epoch) with the expert driving;
* train ``passes`` shuffled passes over the dataset (Adadelta, MSE, mini-batch; naive with
  ``naive_schedule: dagger_steps``: over a random subset of DAgger's epoch-i size), then decay the
  learning rate by ``lr_decay``;
* test MSE on the held-out set, SP (every ``sp_every`` epochs and after the last), TensorBoard
  scalars, a checkpoint (atomic) with everything needed to continue.

A killed run continues with ``--resume``: the dataset on disk keeps every committed row; the
epoch that was running collects only what it still lacks.
"""

from __future__ import annotations

import copy
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.learning.collect import Progress, beta, collect
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_config import DistillConfig
from dls_quadruped.learning.distill_metrics import (
    episode_returns,
    held_out_mse,
    simulation_performance,
    survival,
)
from dls_quadruped.learning.distill_test_set import (
    cut_windows,
    record_expert_episodes,
    window_starts,
)
from dls_quadruped.learning.student import (
    Student,
    encode_labels,
    export_student,
    metadata,
)

CHECKPOINT = "checkpoint.pt"


def collection_seed(seed: int, epoch: int) -> int:
    """Schedule seed the collection restarts from after an evaluation at ``epoch`` (its own episodes,
    not the SP ones continued, and not those of an earlier epoch)."""
    return 100_000 * (seed + 1) + epoch


def rows_per_pass(cfg: DistillConfig, epoch: int, size: int) -> int | None:
    """Rows of one training pass at ``epoch`` (0-based) over a dataset of ``size``: None (all) except
    naive with ``dagger_steps``, which trains on min(size, cap, (epoch + 1) datapoints_per_epoch) rows,
    the size DAgger's dataset has at that epoch (so both make the same gradient steps)."""
    if cfg.algorithm != "naive" or cfg.train.naive_schedule == "full":
        return None
    return min(size, cfg.train.dataset_cap, (epoch + 1) * cfg.train.datapoints_per_epoch)


class DistillTrainer:
    """Holds the env, expert, student, optimiser, datasets and history of one distillation run.

    Args:
        cfg: checked configuration.
        env: the env the expert acts in (``LocomotionEnv``), episodes of 15 s for SP.
        expert: (B, obs_dim) -> (B, 28) raw actions.
        run_dir: where the datasets, checkpoint, TensorBoard events and exports go.
        hidden_dims, activation: student MLP (the expert actor's).
        expert_info: recorded in metrics and the export (path, sha256).
        sp: evaluate SP during training (False: the caller evaluates, e.g. many students batched).
    """

    def __init__(self, cfg: DistillConfig, env, expert, run_dir: Path, hidden_dims, activation: str,
                 expert_info: dict | None = None, printer=print, writer=None, sp: bool = True):
        self.cfg, self.env, self.expert, self.run_dir = cfg, env, expert, Path(run_dir)
        self.print = printer
        self.enc = cfg.encoding.to_encoding()
        self.stride = cfg.encoding.stride(env.step_dt)
        self.obs_dim = int(env.get_observations()["policy"].shape[1])
        self.expert_info = expert_info or {}
        torch.manual_seed(cfg.train.seed)
        self.student = Student(self.obs_dim, self.enc, hidden_dims, activation)
        self.untrained = copy.deepcopy(self.student)  # r_0 of SP (7.2.2)
        self.optimizer = torch.optim.Adadelta(self.student.parameters(), lr=cfg.train.learning_rate)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=1, gamma=cfg.train.lr_decay)
        self.gen = torch.Generator().manual_seed(cfg.train.seed)
        self.meta = metadata(self.enc, cfg.encoding.dt, self.obs_dim, {"stride": self.stride})
        self.epoch = 0  # next epoch to run
        self.written_at_epoch_start = 0
        self.history: list[dict] = []
        self.reference: dict | None = None
        self.dataset: DiskDataset | None = None
        self.test_set: DiskDataset | None = None
        self.writer = writer
        self.sp = sp

    # ------------------------------------------------------------------ datasets
    def _dataset_meta(self) -> dict:
        return {k: self.meta[k] for k in ("encoding", "obs_dim", "output_dim")}

    def open_datasets(self, resume: bool) -> None:
        """Create (fresh run) or reopen (resume) ``dataset/`` and ``test/`` under the run dir."""
        meta = self._dataset_meta()
        for name, cap in (("dataset", self.cfg.train.dataset_cap), ("test", self.cfg.evaluate.test_datapoints)):
            path = self.run_dir / name
            if resume and path.exists():
                ds = DiskDataset.open(path, meta)
            else:
                ds = DiskDataset.create(path, self.obs_dim, self.meta["output_dim"], cap, meta)
            setattr(self, "dataset" if name == "dataset" else "test_set", ds)

    def _labels(self, acts: torch.Tensor) -> torch.Tensor:
        return encode_labels(acts, self.enc)

    def _collect(self, ds: DiskDataset, count: int, beta_value: float, what: str, update_normaliser: bool) -> dict:
        def sink(obs: torch.Tensor, labels: torch.Tensor) -> None:
            ds.append(obs, labels)
            if update_normaliser:  # the student's normaliser follows the aggregated data
                self.student.obs_normalizer.train()
                self.student.obs_normalizer.update(obs)

        with torch.no_grad():
            student = self.student.first_action if beta_value < 1.0 else None
            progress = Progress(what, count, "datapoints", printer=self.print)
            info = collect(self.env, self.expert, self._labels, count, self.enc, self.stride, sink,
                           beta_value=beta_value, student=student, progress=progress)
        progress.update(info["datapoints"], force=True)
        info["datapoints_per_s"] = info["datapoints"] / max(info["seconds"], 1e-9)
        return info

    def collect_test_set(self) -> None:
        """Held-out datapoints cut from whole expert episodes (``distill_test_set``: ``test_episodes``
        episodes of schedule seed ``test_seed``, window starts spread over every phase of them);
        then the env restarts its collection schedule (seed ``train.seed``)."""
        ev = self.cfg.evaluate
        if self.test_set.total_written >= ev.test_datapoints:
            return
        if self.test_set.total_written:  # only a crash inside the single append leaves a partial set
            raise RuntimeError(f"{self.test_set.path} holds a partial test set; delete it to cut it again")
        rng = torch.get_rng_state()
        t0 = time.monotonic()
        record = record_expert_episodes(self.env, self.expert, ev.test_seed, ev.test_episodes)
        span = (self.enc.horizon - 1) * self.stride + 1
        episode, start = window_starts(record.length, span, ev.test_datapoints, seed=ev.test_seed)
        obs, acts = cut_windows(record, episode, start, self.enc.horizon, self.stride)
        self.test_set.append(obs, self._labels(acts))
        self.print(f"[distill] test set: {ev.test_datapoints} windows from {ev.test_episodes} expert episodes "
                   f"({int(record.length.sum())} steps), {time.monotonic() - t0:.0f} s", flush=True)
        torch.set_rng_state(rng)
        self.env.reset(seed=collection_seed(self.cfg.train.seed, -1))

    # ------------------------------------------------------------------ SP
    def _sp_seeds(self) -> list[int]:
        rounds = math.ceil(self.cfg.evaluate.sp_episodes / self.env.num_envs)
        return [self.cfg.evaluate.sp_seed + r for r in range(rounds)]

    def _returns(self, policy) -> dict[str, np.ndarray]:
        rng = torch.get_rng_state()
        try:
            return episode_returns(self.env, policy, self._sp_seeds())
        finally:
            torch.set_rng_state(rng)
            self.env.reset(seed=collection_seed(self.cfg.train.seed, self.epoch))

    def reference_returns(self) -> None:
        """Expert and untrained-student returns on the SP episodes (once per run)."""
        if self.reference is not None:
            return
        t0 = time.monotonic()
        self.print(f"[distill] SP reference: expert and untrained student, {len(self._sp_seeds())} x "
                   f"{self.env.num_envs} episodes of {self.env.max_episode_length_s:g} s", flush=True)
        exp = self._returns(self.expert)
        with torch.no_grad():
            r0 = self._returns(self.untrained.first_action)
        self.reference = {"expert": exp, "untrained": r0, "seconds": time.monotonic() - t0}

    def evaluate_sp(self) -> dict:
        with torch.no_grad():
            stud = self._returns(self.student.first_action)
        out = simulation_performance(stud["return"], self.reference["expert"]["return"],
                                     self.reference["untrained"]["return"], seed=self.epoch)
        out["survival"] = survival(stud["survived"])
        out["survival_expert"] = survival(self.reference["expert"]["survived"])
        return out

    # ------------------------------------------------------------------ training
    def train_pass(self) -> dict:
        """``passes`` shuffled passes of mini-batch MSE steps; returns mean loss and timing."""
        losses, steps, t0 = 0.0, 0, time.monotonic()
        limit = rows_per_pass(self.cfg, self.epoch, len(self.dataset))
        total = self.cfg.train.passes * math.ceil((limit or len(self.dataset)) / self.cfg.train.batch_size)
        progress = Progress(f"epoch {self.epoch + 1}/{self.cfg.train.epochs} training", total, "steps",
                            printer=self.print)
        self.student.train()
        for _ in range(self.cfg.train.passes):
            for obs, labels in self.dataset.minibatches(self.cfg.train.batch_size, self.gen, limit=limit):
                loss = torch.nn.functional.mse_loss(self.student.net(obs), labels)
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                self.optimizer.step()
                losses += loss.item()
                steps += 1
                progress.update(steps, extra=f"loss {losses / steps:.4f}")
        seconds = time.monotonic() - t0
        self.scheduler.step()
        return {"loss": losses / max(steps, 1), "steps": steps, "seconds": seconds,
                "steps_per_s": steps / max(seconds, 1e-9)}

    def _collect_epoch(self) -> dict | None:
        cfg = self.cfg
        if cfg.algorithm == "naive":
            if self.epoch > 0:
                return None
            target = min(cfg.train.dataset_cap, cfg.train.epochs * cfg.train.datapoints_per_epoch)
            b = 1.0
        else:
            target = cfg.train.datapoints_per_epoch
            b = beta(cfg.selector, self.epoch)
        missing = target - (self.dataset.total_written - self.written_at_epoch_start)
        if missing <= 0:
            return {"datapoints": 0, "beta": b, "note": "already collected before the restart"}
        info = self._collect(self.dataset, missing, b, f"epoch {self.epoch + 1}/{cfg.train.epochs} collecting "
                             f"(beta {b:.3g})", update_normaliser=True)
        info["beta"] = b
        return info

    def run_epoch(self) -> dict:
        """Collect (per mode), train, evaluate, log, checkpoint one epoch."""
        cfg = self.cfg
        t0 = time.monotonic()
        collected = self._collect_epoch()
        trained = self.train_pass()
        self.student.eval()
        row = {"epoch": self.epoch + 1, "beta": None if collected is None else collected["beta"],
               "collect": collected, "train": trained, "train_loss": trained["loss"],
               "lr": self.scheduler.get_last_lr()[0], "dataset_size": len(self.dataset),
               "test_mse": held_out_mse(self.student.net, self.test_set)}
        last = self.epoch + 1 == cfg.train.epochs
        every = cfg.evaluate.sp_every
        if self.sp and (last or (every > 0 and (self.epoch + 1) % every == 0)):
            row["sp"] = self.evaluate_sp()
        row["seconds"] = time.monotonic() - t0
        self.history.append(row)
        self._log(row)
        self.epoch += 1
        self.written_at_epoch_start = self.dataset.total_written
        self.save()
        return row

    def _log(self, row: dict) -> None:
        sp = row.get("sp")
        self.print(f"[distill] epoch {row['epoch']}/{self.cfg.train.epochs}: train loss {row['train_loss']:.4f}, "
                   f"test MSE {row['test_mse']:.4f}, dataset {row['dataset_size']}"
                   + (f", SP {100 * sp['sp']:.1f} % [{100 * sp['ci95'][0]:.1f}, {100 * sp['ci95'][1]:.1f}] "
                      f"(n={sp['episodes']}), survival {100 * sp['survival']['rate']:.0f} %" if sp else "")
                   + f", {row['seconds']:.0f} s", flush=True)
        if self.writer is None:
            return
        step = row["epoch"]
        scalars = {"Loss/train_mse": row["train_loss"], "Loss/test_mse": row["test_mse"],
                   "Dataset/size": row["dataset_size"], "Train/learning_rate": row["lr"],
                   "Train/gradient_steps_per_s": row["train"]["steps_per_s"]}
        if row["beta"] is not None:
            scalars["DAgger/beta"] = row["beta"]
        if row["collect"] and row["collect"].get("datapoints"):
            scalars["Collect/datapoints_per_s"] = row["collect"]["datapoints_per_s"]
        if sp:
            scalars.update({"Eval/SP": sp["sp"], "Eval/SP_ci_low": sp["ci95"][0], "Eval/SP_ci_high": sp["ci95"][1],
                            "Eval/survival": sp["survival"]["rate"]})
        for tag, value in scalars.items():
            self.writer.add_scalar(tag, value, step)
        self.writer.flush()

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {"epoch": self.epoch, "student": self.student.state_dict(), "untrained": self.untrained.state_dict(),
                "optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(),
                "generator": self.gen.get_state(), "rng_cpu": torch.get_rng_state(),
                "written_at_epoch_start": self.written_at_epoch_start, "history": self.history,
                "reference": self.reference, "config": self.cfg.to_dict(), "meta": self.meta,
                "expert": self.expert_info}

    def save(self) -> Path:
        path = self.run_dir / CHECKPOINT
        tmp = path.with_name(path.name + ".tmp")
        torch.save(self.state_dict(), tmp)
        os.replace(tmp, path)
        return path

    def load_state_dict(self, state: dict) -> None:
        self.student.load_state_dict(state["student"])
        self.untrained.load_state_dict(state["untrained"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.gen.set_state(state["generator"])
        torch.set_rng_state(state["rng_cpu"])
        self.epoch = int(state["epoch"])
        self.written_at_epoch_start = int(state["written_at_epoch_start"])
        self.history = list(state["history"])
        self.reference = state["reference"]

    def export(self, out_dir: Path) -> Path:
        meta = {**self.meta, "expert": self.expert_info, "algorithm": self.cfg.algorithm,
                "epochs_trained": self.epoch}
        return export_student(self.student, meta, Path(out_dir) / "student.pt2")
