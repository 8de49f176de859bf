"""What a checkpoint keeps of a ``LocomotionEnv`` (``LocomotionEnv.state_dict`` / ``load_state_dict``).

Two parts, so that an env of the same task and number of robots continues bit-identically:

* what outlives an episode: the managers' parts (:data:`MANAGER_STATE`: curriculum state and values, reward weights
  -- the penalty switch --, command ranges, terrain levels), the step counter, the episode schedule's counters and
  the torch RNG state;
* under ``"episodes"``, the episodes in progress (``envs/episode_state.py``: the simulator's whole state and every
  per-robot buffer).

A checkpoint from another number of robots (or one without ``"episodes"``) restores the first part only; the env
then starts every robot's next episode on its restored terrain level, without running the curriculum.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from dls_quadruped.envs import episode_state

if TYPE_CHECKING:
    from dls_quadruped.envs.env import LocomotionEnv

MANAGER_STATE = (("curriculum_state", "curriculum_manager", "state"),
                 ("curriculum_values", "curriculum_manager", "values"),
                 ("reward_weights", "reward_manager", "weights"),
                 ("command_params", "command_manager", "params"),
                 ("terrain_levels", "scene", "terrain_levels"))
"""The managers' parts of the state: (its key, the env's manager attribute, the key in the manager's
``state_dict()``)."""

_LOADED = ("reward_manager", "command_manager", "curriculum_manager", "scene")
"""The managers whose parts :func:`load_env_state_dict` loads, in order."""


def env_state_dict(env: LocomotionEnv) -> dict:
    """The checkpoint state of ``env`` (module doc): a dict of the keys of :data:`MANAGER_STATE`,
    ``common_step_counter``, ``schedule``, ``rng_cpu`` (``rng_cuda`` on a CUDA device) and ``episodes``."""
    parts = {m: getattr(env, m).state_dict() for m in dict.fromkeys(m for _, m, _ in MANAGER_STATE)}
    state = {key: parts[m][k] for key, m, k in MANAGER_STATE}
    state.update(common_step_counter=env.common_step_counter, schedule=env.schedule.state_dict(),
                 rng_cpu=torch.get_rng_state(), episodes=episode_state.capture(env))
    if env.device.type == "cuda":
        state["rng_cuda"] = torch.cuda.get_rng_state(env.device)
    return state


def load_env_state_dict(env: LocomotionEnv, state: dict) -> bool:
    """Load :func:`env_state_dict` output into ``env``, the RNG state aside (:func:`load_rng_state`, last).

    Every manager's part is checked before any is written. Returns whether the episodes in progress were restored
    (saved from as many robots); if not, the caller starts every robot's next episode.

    Raises:
        ValueError: the state does not fit this env (other terms, other number of envs).
    """
    parts: dict[str, dict] = {}
    for key, m, k in MANAGER_STATE:
        parts.setdefault(m, {})[k] = state[key]
    managers = [(getattr(env, m), parts[m]) for m in _LOADED]
    for manager, part in managers:  # every part checked before anything is written
        manager.check_state_dict(part)
    episodes = state.get("episodes")
    if episodes is not None and int(episodes["num_envs"]) != env.num_envs:
        episodes = None  # another --num-envs: fresh episodes
    for manager, part in managers:  # scene: another --num-envs cycles over the saved terrain levels
        manager.load_state_dict(part)
    env.common_step_counter = int(state["common_step_counter"])
    if "schedule" in state:  # checkpoints before the episode schedule have none
        if tuple(state["schedule"]["episode"].shape) == (env.num_envs,):
            env.schedule.load_state_dict(state["schedule"])
        else:  # another --num-envs: a fresh schedule, advanced past the episodes already played
            env.schedule.restart(int(state["schedule"]["seed"]))
            env.schedule.episode[:] = int(state["schedule"]["episode"].max())
    if episodes is None:
        return False
    episode_state.restore(env, episodes)
    return True


def load_rng_state(state: dict, device: torch.device) -> None:
    """The torch RNG state of :func:`env_state_dict` output restored (the CUDA one on a CUDA ``device``)."""
    torch.set_rng_state(state["rng_cpu"])
    if "rng_cuda" in state and device.type == "cuda":
        torch.cuda.set_rng_state(state["rng_cuda"], device)
