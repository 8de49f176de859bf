"""What a checkpoint holds besides rsl-rl's networks and optimiser, so that a run continued from it --
in another directory, on another machine -- takes the iteration the uninterrupted run would have.

Saved by ``AtomicOnPolicyRunner.save`` next to rsl-rl's state and ``env_state``:

- ``rng``: numpy's and Python's global generators (torch's is in ``env_state``, restored last);
- ``logger_state``: rsl-rl's ``Logger`` counters (total steps and time, the rolling episode return
  and length buffers, each robot's running return and length), so the logged curve goes on too;
- ``task``: the task's name and resolved config (``task.yaml``'s content), to refuse another task
  and to name the keys that changed;
- ``agent``: the PPO settings (``agent.yaml`` without the run-length keys);
- ``versions``: of torch, rsl-rl-lib, MuJoCo and numpy (float round-off can differ across them).
"""

from __future__ import annotations

import copy
import random
from collections import deque
from importlib.metadata import PackageNotFoundError, version

import numpy as np

RUN_LENGTH_KEYS = ("max_iterations", "save_interval", "seed", "multi_gpu")
"""Agent settings a continued run may change without changing what an iteration does."""

_LOGGER_TENSORS = ("cur_reward_sum", "cur_episode_length", "cur_ereward_sum", "cur_ireward_sum")
_LOGGER_DEQUES = ("rewbuffer", "lenbuffer", "erewbuffer", "irewbuffer")


def versions() -> dict[str, str]:
    """Installed versions of the libraries whose arithmetic a resumed run repeats."""
    out = {}
    for name in ("torch", "rsl-rl-lib", "mujoco", "numpy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "missing"
    return out


def task_config(env) -> dict:
    """The env's resolved task config without ``scene.num_workers`` (how the simulator is split over
    processes, which does not change the simulation)."""
    data = copy.deepcopy(env.task.data)
    data.get("scene", {}).pop("num_workers", None)
    return data


def agent_config(cfg: dict) -> dict:
    """The runner's config without :data:`RUN_LENGTH_KEYS`."""
    return {k: copy.deepcopy(v) for k, v in cfg.items() if k not in RUN_LENGTH_KEYS}


def capture(runner) -> dict:
    """The resume state of ``runner`` (an ``OnPolicyRunner`` whose env is a ``LocomotionEnv``)."""
    logger = runner.logger
    state = {"rng": {"numpy": np.random.get_state(), "python": random.getstate()},
             "logger_state": {"tot_timesteps": logger.tot_timesteps, "tot_time": logger.tot_time,
                              **{k: getattr(logger, k).cpu().clone() for k in _LOGGER_TENSORS if hasattr(logger, k)},
                              **{k: list(getattr(logger, k)) for k in _LOGGER_DEQUES if hasattr(logger, k)}},
             "agent": agent_config(runner.cfg),
             "versions": versions()}
    if hasattr(runner.env, "task"):
        state["task"] = {"name": runner.env.task.name, "config": task_config(runner.env)}
    return state


def restore(runner, ckpt: dict) -> None:
    """Load :func:`capture`'s part of ``ckpt`` (absent parts, e.g. of older checkpoints, are skipped).

    The logger's per-robot sums are restored only for as many robots as were saved.
    """
    if "rng" in ckpt:
        np.random.set_state(ckpt["rng"]["numpy"])
        random.setstate(ckpt["rng"]["python"])
    saved = ckpt.get("logger_state")
    if saved is None:
        return
    logger = runner.logger
    logger.tot_timesteps, logger.tot_time = saved["tot_timesteps"], saved["tot_time"]
    for k in _LOGGER_TENSORS:
        if k in saved and hasattr(logger, k) and getattr(logger, k).shape == saved[k].shape:
            getattr(logger, k).copy_(saved[k])
    for k in _LOGGER_DEQUES:
        if k in saved and hasattr(logger, k):
            setattr(logger, k, deque(saved[k], maxlen=getattr(logger, k).maxlen))


def differences(saved: dict, current: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested config dicts (added and removed keys too)."""
    out = []
    for k in sorted(set(saved) | set(current), key=str):
        key = f"{prefix}{k}"
        a, b = saved.get(k, "<absent>"), current.get(k, "<absent>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += differences(a, b, key + ".")
        elif a != b:
            out.append(key)
    return out


def mismatch(ckpt: dict, runner) -> str | None:
    """Why ``ckpt`` belongs to another task than ``runner``'s env (None if it does, or if it does not say)."""
    task = ckpt.get("task")
    if task is None or not hasattr(runner.env, "task") or task["name"] == runner.env.task.name:
        return None
    return f"was trained on task '{task['name']}', this is task '{runner.env.task.name}'"


def changes(ckpt: dict, runner) -> list[str]:
    """Task and agent config keys (``task.`` / ``agent.``-prefixed) that differ from the checkpoint's, and
    libraries of another version: the run then continues, but not exactly as the uninterrupted one."""
    out = []
    if "task" in ckpt and hasattr(runner.env, "task"):
        out += differences(ckpt["task"]["config"], task_config(runner.env), "task.")
    if "agent" in ckpt:
        out += differences(ckpt["agent"], agent_config(runner.cfg), "agent.")
    if "versions" in ckpt:
        now = versions()
        out += [f"{k} {v} (now {now.get(k)})" for k, v in ckpt["versions"].items() if now.get(k) != v]
    return out

