"""rsl-rl-lib glue: runner config from the task, atomic checkpoints, resume and policy export.

Runs live in ``<log_root>/<task>/<run_name>/``: ``task.yaml`` (resolved config), ``agent.yaml``,
TensorBoard events, ``model_<it>.pt`` checkpoints (written to a temporary file then renamed, so
a kill never leaves a truncated checkpoint) and ``exported/policy.pt`` (TorchScript) and
``exported/policy.onnx``.
"""

from __future__ import annotations

import copy
import os
import re
from pathlib import Path

import torch
import yaml
from rsl_rl.runners import OnPolicyRunner

_CKPT = re.compile(r"model_(\d+)\.pt$")


class AtomicOnPolicyRunner(OnPolicyRunner):
    """``OnPolicyRunner`` whose checkpoints are written atomically (tmp file + ``os.replace``)."""

    def save(self, path: str, infos: dict | None = None) -> None:
        saved = self.alg.save()
        saved["iter"] = self.current_learning_iteration
        saved["infos"] = infos
        tmp = f"{path}.tmp"
        torch.save(saved, tmp)
        os.replace(tmp, path)  # atomic on POSIX
        self.logger.save_model(path, self.current_learning_iteration)


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
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt") if (m := _CKPT.search(p.name))]
    return max(found)[1] if found else None


def latest_run(task_dir: Path) -> Path | None:
    """Most recently modified run directory of a task that holds a checkpoint."""
    runs = [d for d in Path(task_dir).glob("*") if d.is_dir() and latest_checkpoint(d) is not None]
    return max(runs, key=lambda d: latest_checkpoint(d).stat().st_mtime) if runs else None


def export_policy(runner: OnPolicyRunner, out_dir: Path) -> dict[str, Path | str]:
    """Export the actor (with its observation normaliser) to TorchScript and, if possible, ONNX.

    Returns:
        {"jit": path, "onnx": path or the reason it was skipped}.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    runner.export_policy_to_jit(str(out_dir), "policy.pt")
    result: dict[str, Path | str] = {"jit": out_dir / "policy.pt"}
    try:
        runner.export_policy_to_onnx(str(out_dir), "policy.onnx")
        result["onnx"] = out_dir / "policy.onnx"
    except (ImportError, RuntimeError) as err:  # onnx/onnxscript missing or an exporter failure: report it
        result["onnx"] = f"skipped: {type(err).__name__}: {err}"
    return result


def write_yaml(data: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        yaml.safe_dump(data, fh, sort_keys=False)
