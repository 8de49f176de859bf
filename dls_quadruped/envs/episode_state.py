"""The env's state in the middle of its episodes, for a checkpoint that continues bit-identically.

``LocomotionEnv.state_dict()`` keeps what outlives an episode (curricula, terrain levels, command
ranges, the episode schedule, the RNG). A run resumed from that alone restarts every robot's episode,
so its next iteration is not the one the uninterrupted run would have collected. This module adds the
rest: the simulator's whole state (``VecSim.snapshot``: MuJoCo's integration state incl. the solver's
warm start, the low-level controller's gait phases and trackers, the held references) and every
per-robot buffer of the env and its managers -- episode counters, last actions, commands and their
timers, reward sums, termination flags, interval-event timers, the observation buffer.

The buffers are found, not listed: every tensor (or dict of tensors, or TensorDict) attribute whose
first dimension is ``num_envs`` on the env and on the objects named in ``OWNERS``; so a buffer a
manager gains later is kept without anyone remembering to add it here. Restoring writes into the
existing tensors in place (terms may hold references to them).

Size: 4.6 kB per robot on the base task (1.2 MB for 256 robots), most of it the 259-value observation
buffer and the simulator's float64 state.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

OWNERS = ("", "action_manager", "command_manager", "reward_manager", "termination_manager", "event_manager",
          "scene", "observation_manager")
"""Objects (attribute paths from the env; "" = the env) whose per-robot buffers are saved."""


def _owner(env, path: str):
    return env if path == "" else getattr(env, path)


def _per_robot(value, n: int) -> bool:
    if isinstance(value, (torch.Tensor, TensorDict)):
        return value.ndim >= 1 and value.shape[0] == n
    return isinstance(value, dict) and bool(value) and all(
        isinstance(v, torch.Tensor) and v.ndim >= 1 and v.shape[0] == n for v in value.values())


def capture(env) -> dict:
    """``{"sim": VecSim.snapshot(), "buffers": {owner: {attr: copy on the CPU}}, "num_envs": N}``."""
    n = env.num_envs
    buffers = {}
    for path in OWNERS:
        obj = _owner(env, path)
        found = {}
        for name, value in vars(obj).items():
            if not _per_robot(value, n):
                continue
            if isinstance(value, (dict, TensorDict)):  # a TensorDict as a plain dict: no tensordict pickles
                found[name] = {k: v.detach().cpu().clone() for k, v in value.items()}
            else:
                found[name] = value.detach().cpu().clone()
        buffers[path] = found
    return {"num_envs": n, "sim": env.scene.sim.snapshot(), "buffers": buffers}


def restore(env, state: dict) -> None:
    """Load :func:`capture` output into an env of the same task and number of robots.

    Raises:
        ValueError: another number of robots, or a buffer this env does not have / has in another shape
            (another task); nothing is changed then if the check fails before the first write.
    """
    n = env.num_envs
    if int(state["num_envs"]) != n:
        raise ValueError(f"episode state of {state['num_envs']} robots, this env has {n}")
    for path, saved in state["buffers"].items():  # check everything before writing anything
        obj = _owner(env, path)
        for name, value in saved.items():
            mine = getattr(obj, name, None)
            pairs = value.items() if isinstance(value, dict) else [(None, value)]
            for key, v in pairs:
                keyed = isinstance(mine, (dict, TensorDict))
                target = mine.get(key, None) if keyed else mine
                if key is not None and isinstance(mine, dict) and target is None:
                    continue  # a lazily created entry (e.g. an event timer): created on load
                if target is None or tuple(target.shape) != tuple(v.shape):
                    where = f"{path or 'env'}.{name}" + (f"[{key!r}]" if key is not None else "")
                    raise ValueError(f"episode state {where}: saved shape {tuple(v.shape)}, this env has "
                                     f"{None if target is None else tuple(target.shape)}")
    env.scene.sim.restore(state["sim"])
    for path, saved in state["buffers"].items():
        obj = _owner(env, path)
        for name, value in saved.items():
            mine = getattr(obj, name)
            if isinstance(mine, TensorDict):
                setattr(obj, name, TensorDict({k: v.to(env.device).clone() for k, v in value.items()},
                                              batch_size=[n], device=env.device))
            elif isinstance(mine, dict):
                for key, v in value.items():
                    if key in mine:
                        mine[key].copy_(v)
                    else:
                        mine[key] = v.to(env.device).clone()
            else:
                mine.copy_(value)
    env.refresh_state()
