"""gymnasium views of ``LocomotionEnv``: every task registered, a ``VectorEnv`` and a one-robot ``Env``.

    import gymnasium
    import dls_quadruped.envs.gym_env  # registers dls_quadruped/Base-v0, Rough-v0, Speed-v0, Climb-v0, ...

    envs = gymnasium.make_vec("dls_quadruped/Rough-v0", num_envs=1024, device="cpu", seed=0)
    obs, info = envs.reset(seed=0)                    # {"policy": (1024, 259) tensor}
    obs, reward, terminated, truncated, info = envs.step(actions)   # actions: (1024, 28)

A thin adapter: ``LocomotionEnv`` simulates, resets, rewards and observes; this file only translates
its ``(obs, reward, dones, extras)`` into gymnasium's five values and keeps the episode sums.

Arrays: torch tensors on the env's device, in and out (the env is torch end to end, and on a GPU a
numpy view would copy every observation to the host and every action back). For numpy, wrap with
gymnasium's own converter: ``gymnasium.wrappers.vector.ArrayConversion(envs, env_xp=torch,
target_xp=numpy)`` (needs ``array-api-compat``, installed with this package). The one-robot
``gymnasium.Env`` view returns numpy, as single-environment code expects.

Autoreset: ``AutoresetMode.SAME_STEP``, as the env does it: a robot whose episode ends is reset
inside that ``step``; the returned observation is its new episode's first, ``terminated`` /
``truncated`` say how the old one ended (a fall / the time limit), and
``info["final_obs"]`` (a dict of (N, D) tensors, rows valid where ``info["_final_obs"]``) holds the
old episode's last observation, for bootstrapping a truncated episode. It is computed just before
the reset without consuming any random number, so the episode schedule is the native env's. It
costs one more observation pass (the height scan: ~30 ms at N = 1024 on two cores, ~6 % of a step),
so by default (``final_obs="truncated"``) it is computed on steps where an episode hit its time limit,
for those rows: what bootstrapping needs (a fall's return is not bootstrapped), and rare. ``"all"``
adds the falls (every step, in practice, at large N), ``"none"`` never.

``info``: ``"time_outs"`` (N,) bool (= truncated, rsl-rl's name), ``"log"`` (on steps where an episode ended, the
env's episode means and curriculum values, floats read from ``LocomotionEnv.episode_log``), and where an episode
ended, ``"episode"`` = {"r": return, "l": length [steps], "t": wall time [s]} with mask ``"_episode"``, as
``gymnasium.wrappers.vector.RecordEpisodeStatistics`` writes it (with ``episode_statistics=False`` that wrapper can
write it instead; it refuses to overwrite the key).
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any, ClassVar

import gymnasium
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from dls_quadruped.envs.config import TaskConfig, available_tasks, load_task
from dls_quadruped.envs.gym_spaces import action_space, observation_space

NAMESPACE = "dls_quadruped"
FINAL_OBS_MODES = ("truncated", "all", "none")
"""Which ended episodes get ``info["final_obs"]`` (``LocomotionVectorEnv``)."""


def task_id(task: str) -> str:
    """gymnasium id of a task file name: ``climb_finetune`` -> ``dls_quadruped/ClimbFinetune-v0``."""
    name = "".join(part.capitalize() for part in re.split(r"[_-]", task))
    return f"{NAMESPACE}/{name}-v0"


def _task_config(task: str | Path | TaskConfig, num_workers: int | None, overrides: dict | None) -> TaskConfig | str:
    if isinstance(task, TaskConfig):
        if num_workers is not None or overrides:
            raise ValueError("num_workers and overrides apply to a task name or file, not to a loaded TaskConfig")
        return task
    extra = dict(overrides or {})
    if num_workers is not None:
        extra["scene"] = {**extra.get("scene", {}), "num_workers": num_workers}
    return load_task(task, overrides=extra or None)


class LocomotionVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` robots of one task as a gymnasium ``VectorEnv`` (module docstring).

    Args:
        num_envs: robots N (``gymnasium.make_vec``'s argument; None: the task's ``env.num_envs``).
        task: task name, YAML path or loaded ``TaskConfig``.
        device: torch device of every tensor in and out.
        seed: the env's seed (overrides ``env.seed``); ``reset(seed=...)`` restarts it.
        num_workers: simulator worker processes (overrides ``scene.num_workers``; 0: in-process).
        overrides: dict deep-merged onto the task (as ``load_task``'s).
        final_obs: which ended episodes get ``info["final_obs"]``: "truncated" (time-outs, the default),
            "all" (falls too), "none" (module docstring: an observation pass costs ~6 % of a step).
        episode_statistics: write ``info["episode"]`` (off to use ``RecordEpisodeStatistics``).
        env: an existing ``LocomotionEnv`` to view instead of building one (the other arguments
            except the last three are then ignored).

    Attributes:
        env: the ``LocomotionEnv``.
    """

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int | None = None, task: str | Path | TaskConfig = "base", device: str = "cpu",
                 seed: int | None = None, num_workers: int | None = None, overrides: dict | None = None,
                 final_obs: str = "truncated", episode_statistics: bool = True, env=None):
        if final_obs not in FINAL_OBS_MODES:
            raise ValueError(f"final_obs must be one of {list(FINAL_OBS_MODES)}, got {final_obs!r}")
        built = env is None
        if built:
            from dls_quadruped.envs.env import LocomotionEnv

            env = LocomotionEnv(_task_config(task, num_workers, overrides), num_envs=num_envs, device=device,
                                seed=seed, verbose=False)
        if final_obs != "none" and getattr(env, "graph", None) is not None:  # a graph runs no Python: not this one
            if built:
                env.close()
            raise ValueError(f"final_obs={final_obs!r} observes the robots inside the env step, which "
                             "scene.cuda_graph replays from a graph without running Python; use final_obs='none' "
                             "or scene.cuda_graph: false")
        self.env = env
        self.num_envs = env.num_envs
        self.device = env.device
        self.single_observation_space = observation_space(env)
        self.single_action_space = action_space(env.action_manager.cfg)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.episode_statistics = episode_statistics
        self._returns = torch.zeros(self.num_envs, dtype=torch.float64, device=self.device)  # float64: as numpy's sum
        self._lengths = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self._start_s = torch.full((self.num_envs,), time.perf_counter(), dtype=torch.float64)
        self.final_obs = final_obs
        self._final_obs: dict[str, torch.Tensor] | None = None
        self._stepping = False
        if final_obs != "none":
            self._observe_before_resets()

    # ------------------------------------------------------------------ final observation
    def _observe_before_resets(self) -> None:
        """Wrap the env's ``_reset`` (on this instance only) to observe the robots before a reset in step."""
        reset = self.env._reset

        def observe_then_reset(env_mask: torch.Tensor, *args: Any, **kwargs: Any) -> dict[str, torch.Tensor]:
            ended = self.env.termination_manager.time_outs if self.final_obs == "truncated" else env_mask
            if self._stepping and bool(ended.any()):  # the env's step reads nothing back; this wrapper does
                self._final_obs = self._observe_without_drawing()
            return reset(env_mask, *args, **kwargs)

        self.env._reset = observe_then_reset

    def _observe_without_drawing(self) -> dict[str, torch.Tensor]:
        """Every group's observation now, leaving the episode schedule's counters and torch's RNG as they were
        (noise is drawn from the schedule: a second draw would shift every later one)."""
        schedule = self.env.schedule.state_dict()
        devices = [self.device] if self.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            obs = self.env.observation_manager.compute()
        self.env.schedule.load_state_dict(schedule)
        return {group: value.clone() for group, value in obs.items()}

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Start a new episode on every robot.

        Args:
            seed: restart the env's episode schedule with this seed (the same seed, the same
                episodes: commands, terrain tiles, events, observation noise).
            options: ``{"episode_keys": (N,) ints}`` (with a seed): robot i plays the episodes of key
                ``episode_keys[i]`` (``LocomotionEnv.reset``); nothing else.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        keys = options.pop("episode_keys", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; allowed: ['episode_keys'] (with a seed)")
        if keys is not None:
            keys = torch.as_tensor(keys)
        obs, _ = self.env.reset(seed=seed, episode_keys=keys) if seed is not None or keys is not None \
            else self.env.reset()
        self._returns.zero_()
        self._lengths.zero_()
        self._start_s.fill_(time.perf_counter())
        return dict(obs.items()), {}

    def step(self, actions: torch.Tensor | np.ndarray
             ) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """One policy step of every robot.

        Args:
            actions: (N, 28) raw latent actions (tensor or array; validated by ``LocomotionEnv.check_actions``).

        Returns:
            obs {group: (N, D)}, reward (N,) float32, terminated (N,) bool, truncated (N,) bool, info.
        """
        self._final_obs = None
        self._stepping = True
        try:
            obs, reward, dones, extras = self.env.step(actions)
        finally:
            self._stepping = False
        dones = dones.bool()
        truncated = extras["time_outs"].bool()
        terminated = dones & ~truncated
        self._returns += reward.double()
        self._lengths += 1
        info: dict[str, Any] = {"time_outs": truncated.clone(), "log": {}}
        if dones.any():
            info["log"] = self.env.episode_log.read()
            now = time.perf_counter()
            if self.episode_statistics:
                zero = torch.zeros((), dtype=torch.float64, device=self.device)
                info["episode"] = {"r": torch.where(dones, self._returns, zero),
                                   "l": torch.where(dones, self._lengths, 0),
                                   "t": torch.where(dones, (now - self._start_s).to(self.device), zero)}
                info["_episode"] = dones.clone()
            if self._final_obs is not None:
                info["final_obs"] = self._final_obs
                info["_final_obs"] = (dones if self.final_obs == "all" else truncated).clone()
            self._returns[dones] = 0.0
            self._lengths[dones] = 0
            self._start_s[dones.cpu()] = now
        return dict(obs.items()), reward, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the simulator (its worker processes)."""
        self.env.close()


RENDER_SIZE = (360, 480)
"""(height, width) [pixels] of ``render()``'s frames, as ``make play``'s video."""


class _RobotCamera:
    """Offscreen frames of robot 0 with a tracking camera (MuJoCo's renderer on a local ``MjData`` of the env's
    model; needs an OpenGL platform: ``MUJOCO_GL=egl`` or ``osmesa``)."""

    def __init__(self, model, size: tuple[int, int] = RENDER_SIZE):
        import mujoco

        self._mujoco, self.model, self.data = mujoco, model, mujoco.MjData(model)
        self.renderer = mujoco.Renderer(model, *size)
        self.camera = mujoco.MjvCamera()
        self.camera.distance, self.camera.azimuth, self.camera.elevation = 2.0, 135.0, -20.0
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:4] = 1  # the robot's collision primitives (group 3) are its only body shapes

    def frame(self, env) -> np.ndarray:
        """(H, W, 3) uint8 RGB of robot 0 of ``env`` (a ``LocomotionEnv``) now."""
        s = env.state
        self.data.qpos[:3] = s.base_pos_w[0].cpu().numpy()
        self.data.qpos[3:7] = s.base_quat_w[0].cpu().numpy()
        self.data.qpos[7:19] = s.joint_pos[0].cpu().numpy()
        self._mujoco.mj_forward(self.model, self.data)
        self.camera.lookat[:] = self.data.qpos[:3]
        self.renderer.update_scene(self.data, camera=self.camera, scene_option=self.option)
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()


class LocomotionGymEnv(gymnasium.Env):
    """One robot of a task as a gymnasium ``Env``, numpy in and out (passes ``check_env``).

    A view of a one-robot :class:`LocomotionVectorEnv` (same arguments, without ``num_envs``). When an
    episode ends, ``step`` returns its last observation; the env has already started the next
    episode, which the following ``reset()`` (without a seed) hands out instead of resetting again.

    Args (besides the vector view's):
        render_mode: None or ``"rgb_array"``: ``render()`` returns an (H, W, 3) uint8 frame of the robot
            (MuJoCo's offscreen renderer, as ``make play``; gymnasium's ``RecordVideo`` records it).
        normalize_actions: the action space is ``Box(-1, 1, (28,))`` and an action u is the raw latent
            action ``low + (u + 1) / 2 (high - low)`` of the raw box (``gym_spaces.action_bounds``), the
            symmetric, normalised box libraries such as Stable-Baselines3 expect; False: the raw box.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, task: str | Path | TaskConfig = "base", device: str = "cpu", seed: int | None = None,
                 num_workers: int | None = None, overrides: dict | None = None, render_mode: str | None = None,
                 normalize_actions: bool = False):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.vec = LocomotionVectorEnv(1, task, device, seed, num_workers, overrides, final_obs="all")
        self.observation_space = self.vec.single_observation_space
        raw = self.vec.single_action_space
        self.normalize_actions = bool(normalize_actions)
        self._raw_low, self._raw_span = raw.low, raw.high - raw.low
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, raw.shape, np.float32) if self.normalize_actions else raw
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.vec.env.step_dt)}
        self._camera: _RobotCamera | None = None
        self._next_obs: dict[str, torch.Tensor] | None = None

    def raw_action(self, action: np.ndarray) -> np.ndarray:
        """(28,) the raw latent action ``step`` applies for ``action`` (itself without ``normalize_actions``)."""
        action = np.asarray(action, dtype=np.float32)
        if not self.normalize_actions:
            return action
        return (self._raw_low + (action + 1.0) * 0.5 * self._raw_span).astype(np.float32)

    def render(self) -> np.ndarray | None:
        """(H, W, 3) uint8 frame of the robot with ``render_mode="rgb_array"``; None without a render mode."""
        if self.render_mode is None:
            return None
        if self._camera is None:
            self._camera = _RobotCamera(self.vec.env.scene.model)
        return self._camera.frame(self.vec.env)

    @staticmethod
    def _first(obs: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
        return {group: value[0].detach().cpu().numpy().copy() for group, value in obs.items()}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        if seed is None and not options and self._next_obs is not None:  # started when the last episode ended
            obs = self._next_obs
        else:
            obs, _ = self.vec.reset(seed=seed, options=options)
        self._next_obs = None
        return self._first(obs), {}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Args: action (28,) raw latent action (in [-1, 1] with ``normalize_actions``). Returns obs, reward,
        terminated, truncated, info
        (``"time_out"``; at an episode's end ``"episode"`` {"r", "l", "t"})."""
        if np.shape(action) != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {np.shape(action)}")
        action = torch.as_tensor(self.raw_action(action))
        obs, reward, terminated, truncated, info = self.vec.step(action[None])
        out: dict[str, Any] = {"time_out": bool(truncated[0])}
        if "final_obs" in info:  # the episode ended: hand out its last observation, keep the new one
            self._next_obs, obs = obs, info["final_obs"]
        if "episode" in info:
            out["episode"] = {"r": float(info["episode"]["r"][0]), "l": int(info["episode"]["l"][0]),
                              "t": float(info["episode"]["t"][0])}
        return self._first(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), out

    def close(self) -> None:
        if self._camera is not None:
            self._camera.close()
            self._camera = None
        self.vec.close()


def register_tasks() -> list[str]:
    """Register every task of ``tasks/`` (not the ``_`` fragments) with gymnasium; returns the ids.

    ``make_vec(id, num_envs=N, **kwargs)`` builds a :class:`LocomotionVectorEnv`, ``make(id, **kwargs)``
    a :class:`LocomotionGymEnv`; kwargs are their constructor arguments. Idempotent.
    """
    ids = []
    for task in available_tasks():
        env_id = task_id(task)
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=f"{__name__}:LocomotionGymEnv",
                               vector_entry_point=f"{__name__}:LocomotionVectorEnv", kwargs={"task": task},
                               disable_env_checker=True)  # check_env is run by the tests instead
        ids.append(env_id)
    return ids


TASK_IDS = register_tasks()
