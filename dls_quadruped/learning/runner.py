"""rsl-rl-lib glue: runner config from the task, atomic checkpoints, resume and policy export.

Runs live in ``<log_root>/<task>/<run_name>/``: ``task.yaml`` (resolved config), ``agent.yaml``,
TensorBoard events, ``model_<it>.pt`` checkpoints (written to a temporary file then renamed, so
a kill never leaves a truncated checkpoint) and ``exported/policy.pt2`` (a ``torch.export`` program,
``learning/policy_file.py``) and ``exported/policy.onnx`` (both any batch size, weights embedded).

A checkpoint holds rsl-rl's own state plus ``env_state`` (``LocomotionEnv.state_dict()``: curricula,
terrain levels, command ranges, reward weights, RNG, the episodes in progress), ``obs_dims``/
``num_actions`` and the task's name so a resume onto another task is refused before anything is
written, and ``learning/resume_state.py``'s part (numpy/python RNG, logger counters, configs,
versions): a run continued from it, anywhere, takes the iteration the uninterrupted run would have.
Checkpoints are read without running code from them (``learning/checkpoint_file.py``).
``copy_to`` names a second file every checkpoint is also written to (atomically; one to commit).
Besides rsl-rl's every-``save_interval`` saves, the runner saves when ``save_every_s`` seconds of
wall time passed since the last save and, after SIGINT/SIGTERM, at the end of the current
iteration (then raises ``TrainingInterrupted``). With a ``deadline`` (``train --time-limit``) it also stops
at the end of the last iteration that leaves time for one more iteration and the closing save and export
(raises ``TimeLimitReached`` after saving). Every iteration also logs ``learning/diagnostics.py``'s
``Diagnostics/*`` scalars (action std and clip fractions per latent-action group, ignored F/p, KL, learning
rate) and prints them on one line, and hands rsl-rl's logger the env's episode values, summed on the device over
the iteration (``LocomotionEnv.episode_log``).

Under torchrun the runner joins the process group with gloo on the CPU and NCCL on GPUs
(``learning/distributed.py``; rsl-rl-lib itself only knows NCCL); rsl-rl all-reduces the gradients,
the KL and the normaliser statistics and only rank 0 logs and saves. A stop signal on any rank
stops every rank at the end of the same iteration.
"""

from __future__ import annotations

import copy
import hashlib
import os
import re
import signal
import threading
import time
from pathlib import Path

import torch
import yaml
from rsl_rl.runners import OnPolicyRunner

from dls_quadruped.learning import checkpoint_file, resume_state, time_limit
from dls_quadruped.learning.checkpoint_file import UnsafeCheckpoint
from dls_quadruped.learning.diagnostics import TrainingDiagnostics
from dls_quadruped.learning.distributed import any_rank, init_distributed
from dls_quadruped.learning.fast_update import speed_up_update
from dls_quadruped.learning.policy_export import export_actor_onnx
from dls_quadruped.learning.symmetry import check_symmetry_cfg
from dls_quadruped.learning.time_limit import Deadline, TimeLimitReached

_CKPT = re.compile(r"model_(\d+)\.pt$")


class TrainingInterrupted(Exception):
    """SIGINT/SIGTERM arrived; the last finished iteration was saved to ``path`` (None: nothing to save)."""

    def __init__(self, signum: int, path: str | None):
        self.signum, self.path = signum, path
        super().__init__(f"{signal.Signals(signum).name}: saved {path}" if path else signal.Signals(signum).name)


class AtomicOnPolicyRunner(OnPolicyRunner):
    """``OnPolicyRunner`` with atomic checkpoints (tmp file + ``os.replace``) that carry the env state,
    wall-time saves and a save on SIGINT/SIGTERM. Arguments not listed are ``OnPolicyRunner``'s.

    Args:
        save_every_s: also save when this many seconds passed since the last save (None: never).
        fast_update: make rsl-rl's PPO update cheaper without changing its numbers
            (``learning/fast_update.py``); False: rsl-rl's stock update.
        update_threads: with ``fast_update``, torch threads during the update (None: every core).
        deadline: stop (save, then raise ``TimeLimitReached``) at the end of the last iteration the
            deadline leaves room for (None: no limit).
    """

    def __init__(self, env, train_cfg: dict, log_dir: str | None = None, device: str = "cpu",
                 save_every_s: float | None = None, fast_update: bool = True, update_threads: int | None = None,
                 deadline: Deadline | None = None):
        check_symmetry_cfg(env, train_cfg)  # a bad mirror map fails here, naming its term
        super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        if fast_update:
            speed_up_update(self.alg, update_threads)  # before any checkpoint loads into the optimiser
        self.diagnostics = TrainingDiagnostics.attach(self)
        self.save_every_s = save_every_s
        self.copy_to: str | None = None  # every checkpoint is also written here (train --checkpoint-copy)
        self.stop_signal: int | None = None
        self._last_save_time = time.monotonic()
        self._last_saved: tuple[str, int] | None = None
        self.deadline = deadline
        self._iteration_end = time_limit.clock()  # the first iteration's time includes the env's first steps (compiles)
        log = self.logger.log

        def log_then_checkpoint(*args, **kwargs) -> None:
            # rsl-rl calls logger.log once per iteration, after the update and before its own save
            self._collect_episode_log()
            log(*args, **kwargs)
            self._log_diagnostics(kwargs["it"])
            self._end_of_iteration()

        self.logger.log = log_then_checkpoint

    def _configure_multi_gpu(self) -> None:
        """rsl-rl's hook, called first in ``__init__``: join torchrun's process group with the backend
        that fits ``self.device`` (gloo on cpu, NCCL on ``cuda:<LOCAL_RANK>``) and fill the fields and
        ``cfg["multi_gpu"]`` that rsl-rl's PPO and logger read."""
        ranks = init_distributed(self.device)  # a no-op for a single process, reused if train.py joined
        self.ranks = ranks
        self.gpu_world_size, self.gpu_global_rank, self.gpu_local_rank = ranks.world_size, ranks.rank, ranks.local_rank
        self.is_distributed = ranks.is_distributed
        self.cfg["multi_gpu"] = ({"global_rank": ranks.rank, "local_rank": ranks.local_rank,
                                  "world_size": ranks.world_size} if ranks.is_distributed else None)

    # ------------------------------------------------------------------ signals
    def install_signal_handlers(self) -> dict:
        """First SIGINT/SIGTERM: finish the iteration, save, raise ``TrainingInterrupted``; second: stop now.

        Returns the previous handlers (give them to ``signal.signal`` to restore); empty outside the
        main thread, where Python allows no handlers.
        """
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

        def handler(signum, frame):
            if self.stop_signal is not None:
                signal.signal(signal.SIGINT, signal.default_int_handler)
                raise KeyboardInterrupt
            self.stop_signal = signum
            print(f"[train] {signal.Signals(signum).name}: saving at the end of this iteration "
                  "(send it again to stop without saving)", flush=True)

        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)
        return previous

    def _collect_episode_log(self) -> None:
        """Hand rsl-rl's logger the iteration's episode values: the env sums them on the device
        (``LocomotionEnv.episode_log``) and they are read here, once per iteration, instead of being handed over at
        every step (``extras["log"]``, which the logger would read one step at a time). Every rank reads (and
        restarts) its sums; rank 0 logs them."""
        episode_log = getattr(self.env, "episode_log", None)
        values = {} if episode_log is None else episode_log.read()
        if values and self.logger.writer is not None:
            self.logger.ep_extras.append(values)

    def _log_diagnostics(self, it: int) -> None:
        """Write the iteration's ``TrainingDiagnostics`` as ``Diagnostics/<name>`` scalars and one console line."""
        values = self.diagnostics.scalars()  # every rank: it also restarts the rollout's sums
        if self.logger.writer is None:
            return
        for name, value in values.items():
            self.logger.writer.add_scalar(f"Diagnostics/{name}", value, it)
        print(TrainingDiagnostics.summary(values), flush=True)

    def _out_of_time(self) -> bool:
        """Whether the deadline leaves no room for another iteration (rank 0 decides, every rank follows)."""
        if self.deadline is None:
            return False
        now = time_limit.clock()
        iteration_s, self._iteration_end = now - self._iteration_end, now
        late = self.deadline.stop_after(iteration_s, now) if self.ranks.is_main else False
        return bool(any_rank(int(late), self.ranks, self.device))

    def _end_of_iteration(self) -> None:
        stop = any_rank(self.stop_signal or 0, self.ranks, self.device)
        self.stop_signal = stop or None
        late = self._out_of_time()
        path = None
        if self.logger.writer is not None:  # rank 0 with a log dir
            due = self.save_every_s is not None and time.monotonic() - self._last_save_time >= self.save_every_s
            if due or late or self.stop_signal is not None:
                path = os.path.join(self.logger.log_dir, f"model_{self.current_learning_iteration}.pt")
                self.save(path)
        if self.stop_signal is not None or late:
            self.logger.stop_logging_writer()
            if self.stop_signal is not None:
                raise TrainingInterrupted(self.stop_signal, path)
            raise TimeLimitReached(path, self.current_learning_iteration)

    # ------------------------------------------------------------------ export
    def export_policy_to_onnx(self, path: str, filename: str = "policy.onnx", verbose: bool = False) -> None:
        """The deterministic actor (with its normaliser) as one self-contained ONNX file whose batch size
        is free: input ``obs`` (batch, obs_dim), output ``actions`` (batch, num_actions).

        rsl-rl's own export fixes the batch to 1 and writes the weights to a ``.data`` file beside it.
        """
        export_actor_onnx(self.alg.get_policy(), Path(path) / filename, verbose=verbose)

    # ------------------------------------------------------------------ checkpoints
    def save(self, path: str, infos: dict | None = None) -> None:
        key = (os.path.abspath(path), self.current_learning_iteration)
        if key == self._last_saved and os.path.exists(path):
            return  # the same iteration was just saved (wall-time save, then rsl-rl's own)
        saved = self.alg.save()
        saved["iter"] = self.current_learning_iteration
        saved["infos"] = infos
        if hasattr(self.env, "state_dict"):
            saved["env_state"] = self.env.state_dict()
            saved["obs_dims"] = dict(self.env.obs_dims)
            saved["num_actions"] = int(self.env.num_actions)
        saved.update(resume_state.capture(self))  # numpy/python RNG, logger counters, task, versions
        for target in (path, self.copy_to) if self.copy_to else (path,):
            tmp = f"{target}.tmp"
            torch.save(saved, tmp)
            os.replace(tmp, target)  # atomic on POSIX
        self._last_saved = key
        self._last_save_time = time.monotonic()
        self.logger.save_model(path, self.current_learning_iteration)

    def load_checkpoint(self, ckpt: dict, path: str, env_state: bool = True, check_task: bool = True) -> None:
        """Load an already read checkpoint: networks, optimiser, iteration and (if saved and
        ``env_state``) the env state.

        Raises:
            CheckpointMismatch: the checkpoint was trained on other observation or action sizes, or
                (``check_task``) on a task of another name.
        """
        self._check_sizes(ckpt, path)
        if check_task and (why := resume_state.mismatch(ckpt, self)) is not None:
            raise CheckpointMismatch(f"{path} {why}")
        try:
            self.alg.load(ckpt, None, True)
        except (RuntimeError, KeyError) as err:  # size mismatch of a checkpoint without obs_dims
            raise CheckpointMismatch(_load_error(path, err)) from err
        self.current_learning_iteration = ckpt["iter"]
        if env_state and "env_state" in ckpt and hasattr(self.env, "load_state_dict"):
            try:
                self.env.load_state_dict(ckpt["env_state"])
            except (KeyError, ValueError) as err:
                raise CheckpointMismatch(f"{path}: env state does not fit this task: {err}") from err
        resume_state.restore(self, ckpt)


    def init_networks(self, ckpt: dict, path: str) -> None:
        """Start a new run from another run's networks (``--init-from``): the actor (with its action
        std) and the critic are loaded, observation normalisers included; the optimiser, the
        iteration counter and the env state (curricula, terrain levels, command ranges) start afresh.

        The normalisers keep their statistics *and* sample counts, so every input keeps the meaning
        the networks were trained with and the new task's observations move the statistics only as
        fast as further training would have. (Lowering the counts so the new task's statistics take
        over at once was tried and is wrong: a speed command range of [0, 1] m/s re-centres the
        command input on 0.5 m/s, which the base actor reads as "stand still"; those runs fell.)

        Raises:
            CheckpointMismatch: the checkpoint was trained on other observation or action sizes, or
                its networks do not fit this task's (hidden sizes).
        """
        self._check_sizes(ckpt, path)
        try:
            self.alg.load(ckpt, {"actor": True, "critic": True}, True)
        except (RuntimeError, KeyError) as err:
            raise CheckpointMismatch(_load_error(path, err)) from err
        self.current_learning_iteration = 0

    def set_action_std(self, std: float) -> None:
        """Set every action dimension's exploration std of the actor's Gaussian to ``std`` (its
        ``std_param``, or ``log_std_param`` for a log parameterisation)."""
        dist = self.alg.get_policy().distribution
        with torch.no_grad():
            if getattr(dist, "std_type", "scalar") == "log":
                dist.log_std_param.fill_(float(torch.log(torch.tensor(std))))
            else:
                dist.std_param.fill_(std)

    def _check_sizes(self, ckpt: dict, path: str) -> None:
        env_dims = dict(self.env.obs_dims)
        if "obs_dims" in ckpt and (ckpt["obs_dims"] != env_dims or ckpt["num_actions"] != self.env.num_actions):
            trained_on = f" on task '{ckpt['task']['name']}'" if "task" in ckpt else ""
            here = f"task '{self.env.task.name}'" if hasattr(self.env, "task") else "this task"
            raise CheckpointMismatch(f"{path} was trained with observations {ckpt['obs_dims']} and "
                                     f"{ckpt['num_actions']} actions{trained_on}; {here} has {env_dims} and "
                                     f"{self.env.num_actions}")


def _load_error(path: str, err: Exception) -> str:
    first = str(err).strip().splitlines()
    return f"{path} does not fit this task's networks: {' '.join(line.strip() for line in first[:3])}"


class CheckpointMismatch(ValueError):
    """A checkpoint does not fit the task it is loaded into."""


def read_checkpoint(path: Path) -> dict:
    """Load a checkpoint on the CPU without running code from it (:func:`checkpoint_file.load`); any failure
    (truncated, not a checkpoint, naming a function to call) -> ``ValueError``, one line."""
    try:
        ckpt = checkpoint_file.load(path)
    except UnsafeCheckpoint:
        raise
    except Exception as err:  # unpickling fails in many ways; all mean "unreadable"
        raise ValueError(f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}") from err
    if not isinstance(ckpt, dict) or "iter" not in ckpt or "actor_state_dict" not in ckpt:
        raise ValueError("not an rsl-rl checkpoint (no 'iter'/'actor_state_dict')")
    return ckpt


def newest_readable_checkpoint(run_dir: Path, note=print, prog: str = "train") -> tuple[Path, dict] | None:
    """The highest-iteration ``model_<it>.pt`` of ``run_dir`` that loads, and its contents.

    Unreadable ones are skipped with a one-line ``note`` naming them (``[<prog>] note: ...``).
    """
    for _, path in sorted(checkpoints(run_dir), reverse=True):
        try:
            return path, read_checkpoint(path)
        except ValueError as err:
            note(f"[{prog}] note: skipping unreadable checkpoint {path} ({err})")
    return None


def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """(iteration, path) of every ``model_<it>.pt`` in ``run_dir``."""
    return [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt") if (m := _CKPT.search(p.name))]


def remove_stale_tmp(run_dir: Path) -> list[Path]:
    """Delete ``*.pt.tmp`` left by a save that was killed half-way; returns what was removed."""
    stale = sorted(Path(run_dir).glob("*.pt.tmp"))
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def new_run_dir(task_dir: Path) -> Path:
    """Create ``<task_dir>/<date_time>`` (``_2``, ``_3`` ... if taken, e.g. two runs in one second)."""
    stem = task_dir / time.strftime("%Y-%m-%d_%H-%M-%S")
    task_dir.mkdir(parents=True, exist_ok=True)
    for k in range(1, 1000):
        run_dir = stem if k == 1 else stem.with_name(f"{stem.name}_{k}")
        try:
            run_dir.mkdir()  # atomic: exactly one process creates a given name
            return run_dir
        except FileExistsError:
            continue
    raise RuntimeError(f"could not create a new run directory next to {stem}")


def runner_config(agent: dict, iterations: int | None = None, seed: int | None = None) -> dict:
    """rsl-rl 5.x ``train_cfg`` from the task's ``agent`` section (a deep copy)."""
    cfg = copy.deepcopy(agent)
    if iterations is not None:
        cfg["max_iterations"] = iterations
    if seed is not None:
        cfg["seed"] = seed
    return cfg


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The ``model_<it>.pt`` with the highest iteration in ``run_dir`` (None if there is none)."""
    found = checkpoints(run_dir)
    return max(found)[1] if found else None


def latest_run(task_dir: Path) -> Path | None:
    """Most recently modified run directory of a task that holds a checkpoint."""
    runs = [d for d in Path(task_dir).glob("*") if d.is_dir() and latest_checkpoint(d) is not None]
    return max(runs, key=lambda d: latest_checkpoint(d).stat().st_mtime) if runs else None


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (records which expert or checkpoint a run started from)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_yaml(data: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        yaml.safe_dump(data, fh, sort_keys=False)
