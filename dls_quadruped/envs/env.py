"""Manager-based locomotion env implementing rsl-rl-lib 5.x's ``VecEnv``.

Step order (IsaacLab's ``ManagerBasedRLEnv.step``):

1. action manager: raw (B, 28) -> world references -> the backend's ``set_references``;
2. the simulator backend's ``step(decimation)`` (``sim/interface.py``): 4 physics steps at 200 Hz, low-level control
   at every one;
3. episode counters += 1; termination manager -> dones (terminated | time_outs);
4. reward manager -> reward (weights x dt);
5. reset the done envs, by their (B,) mask: curriculum (reads their episode data) -> reset events (placement,
   joint randomisation, wrench) -> every manager's reset (episode logs) -> counters = 0;
6. command manager: resample expired commands; interval events (pushes), by masks too;
7. observation manager -> TensorDict of groups.

Returns ``(obs, reward, dones, extras)`` with ``extras["time_outs"]`` (time limits, bootstrapped by PPO) and an
empty ``extras["log"]``: the episode values (episode means of the reward terms, termination counts, curriculum
values, and ``Episode_Metric/lin_vel_xy_error``: mean over the resetting envs of the per-step planar velocity-tracking
error |v_xy,b - v_cmd,xy| [m/s] averaged over their episode) are summed on the device in :attr:`episode_log`
(``envs/episode_log.py``) and read once per PPO iteration (``learning/runner.py``; ``episode_log.read()``). The
last observation of a reset env is the first one of its new episode (as in IsaacLab).

Host reads: none. Resets and pushes are (B,) masks with static shapes: every robot's values are computed, the masked
ones kept (``torch.where``; the ``cpu`` backend turns masks into row ids itself), draws count only for the masked
robots (``EpisodeSchedule.only``), curricula decide on the device (``tests/envs/test_host_sync.py``).

What terms see (``env.<attr>``): ``state`` (RobotState on ``device``), ``num_envs``, ``device``, ``step_dt`` [s],
``max_episode_length`` [steps], ``max_episode_length_s``, ``episode_length_buf``, ``robot_weight`` [N], and the
managers ``scene``, ``action_manager``, ``command_manager``, ``reward_manager``, ``curriculum_manager``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from dls_quadruped.core.compile import FusedCache, compile_wanted, fused_method
from dls_quadruped.core.state import RobotState
from dls_quadruped.envs import checkpoint_state, env_graph
from dls_quadruped.envs.config import TaskConfig, load_task, save_resolved
from dls_quadruped.envs.episode_log import EpisodeLog
from dls_quadruped.envs.managers.action import ActionManager
from dls_quadruped.envs.managers.command import CommandManager
from dls_quadruped.envs.managers.curriculum import CurriculumManager
from dls_quadruped.envs.managers.event import EventManager
from dls_quadruped.envs.managers.observation import ObservationManager
from dls_quadruped.envs.managers.reward import RewardManager
from dls_quadruped.envs.managers.scene import SceneManager
from dls_quadruped.envs.managers.termination import TerminationManager
from dls_quadruped.envs.mdp import events as event_mdp
from dls_quadruped.envs.mdp import observations as obs_mdp
from dls_quadruped.envs.schedule import EpisodeSchedule
from dls_quadruped.envs.value_checks import dataclass_from_dict


@dataclass(frozen=True)
class EnvConfig:
    """``env`` section: num_envs, episode_length_s [s] (15), decimation (4 physics steps per policy step), seed."""

    num_envs: int = field(default=64, metadata={"min": 1})
    episode_length_s: float = field(default=15.0, metadata={"gt": 0.0})
    decimation: int = field(default=4, metadata={"min": 1})
    seed: int = 0


class LocomotionEnv(VecEnv):
    """N AlienGo robots with the latent action, managed as in IsaacLab.

    Args:
        task: task name, YAML path or loaded ``TaskConfig``.
        num_envs: overrides ``env.num_envs``.
        device: torch device of observations, rewards and actions.
        seed: overrides ``env.seed``.
        run_dir: if given, the resolved config is written to ``run_dir/task.yaml``. verbose: print the term tables.
    """

    def __init__(self, task: str | Path | TaskConfig, num_envs: int | None = None, device: str = "cpu",
                 seed: int | None = None, run_dir: Path | None = None, verbose: bool = True):
        self.task = task if isinstance(task, TaskConfig) else load_task(task)
        self.env_cfg = dataclass_from_dict(EnvConfig, self.task.section("env"), self.task, "env")
        self.num_envs = self.env_cfg.num_envs if num_envs is None else num_envs
        if isinstance(self.num_envs, bool) or not isinstance(self.num_envs, int) or self.num_envs < 1:
            # 0 is refused, not read as the default
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.device = torch.device(device)
        self.seed = self.env_cfg.seed if seed is None else seed
        torch.manual_seed(self.seed)
        self.schedule = EpisodeSchedule(self.seed, self.num_envs, self.device)
        self.cfg = self.task.data
        self.scene = SceneManager(self.task, self)
        # scene.compile (docs/gpu.md): the schedule's draws and the managers' computes compiled into fused kernels
        self.compile = compile_wanted(self.scene.cfg.compile, self.device)
        self.schedule.compile = self.compile
        self.physics_dt = self.scene.sim.physics_dt
        self.decimation = self.env_cfg.decimation
        self.step_dt = self.physics_dt * self.decimation
        self.max_episode_length_s = self.env_cfg.episode_length_s
        self.max_episode_length = math.ceil(self.max_episode_length_s / self.step_dt)
        self.robot_weight = self.scene.sim.total_weight()
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self._every_env = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)  # a full reset's mask
        self.common_step_counter = 0
        self._generation = 0  # graph_generation: bumped by reset and load_state_dict
        self._controlled_steps: int | None = None  # physics steps of the step_controlled in progress
        # sum over the episode of |v_xy - cmd_xy| [m/s]
        self._vel_err_sum = torch.zeros(self.num_envs, device=self.device)
        self._state = self._to_device(self.scene.sim.state)
        self.command_manager = CommandManager(self.task, self)
        self.action_manager = ActionManager(self.task, self)
        self.num_actions = self.action_manager.num_actions
        self.observation_manager = ObservationManager(self.task, self)
        self.reward_manager = RewardManager(self.task, self)
        self.termination_manager = TerminationManager(self.task, self)
        self.event_manager = EventManager(self.task, self)
        self.fused = FusedCache(self.compile)  # torch work compiled where the scene compiles
        self.episode_log = EpisodeLog(self.device)  # the steps' episode values, summed on the device
        self.curriculum_manager = CurriculumManager(self.task, self)
        placements = [t for t in self.event_manager.terms
                      if t.func in event_mdp.PLACEMENT_EVENTS and t.extra["mode"] == "reset"]
        if not placements:
            raise self.task.error("events", "a 'reset' mode event with func reset_robot or reset_home is required "
                                            "(it places robots)")
        self.extras: dict = {"log": {}}
        self.event_manager.apply("startup")
        self.curriculum_manager.start()
        # no curriculum here: it would judge robots that were never placed (and move their rows)
        self._reset(self._every_env, curriculum=False)
        self.obs_buf = self.observation_manager.compute()
        self.graph = env_graph.make(self)
        """The step's captured graph (``scene.cuda_graph``, ``envs/env_graph.py``), or None."""
        if run_dir is not None:
            save_resolved(self.task, Path(run_dir) / "task.yaml")
        if verbose:
            print(self.summary())

    # ------------------------------------------------------------------ state
    def _to_device(self, state: RobotState) -> RobotState:
        """The backend's state on ``self.device``: the backend's live buffers themselves when both are on one
        device (no copy), else a copy."""
        return state if state.base_pos_w.device == self.device else state.to(self.device)

    @property
    def state(self) -> RobotState:
        """Latest robot state on ``self.device`` (refreshed after each simulator call)."""
        return self._state

    def refresh_state(self) -> None:
        """Re-read the robot state from the simulator (after stepping it outside :meth:`step`)."""
        self._state = self._to_device(self.scene.sim.state)

    @property
    def obs_dims(self) -> dict[str, int]:
        return {g: v.shape[1] for g, v in self.obs_buf.items()}

    # ------------------------------------------------------------------ VecEnv
    def get_observations(self) -> TensorDict:
        return self.obs_buf

    def check_actions(self, actions: torch.Tensor | np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """Validate a batch of actions before any buffer is touched.

        Args:
            actions: (num_envs, num_actions) tensor or numpy array, any float dtype and device;
                autograd history is dropped (a policy called outside ``torch.no_grad``).

        Returns:
            (actions on ``device`` as float32 with non-finite rows replaced by zeros,
                (num_envs,) bool mask of the rows that were not finite: NaN/inf, or an entry whose physical
                value overflows, as -3e38 does in a force, ``ActionManager.finite_rows``).

        Raises:
            TypeError: not a tensor/array of numbers.
            ValueError: wrong shape (no broadcasting: a (28,) or (1, 28) action for a batch of robots is an error).
        """
        return self._zero_nonfinite(self._device_actions(actions))

    def _device_actions(self, actions: torch.Tensor | np.ndarray) -> torch.Tensor:
        """The host checks of :meth:`check_actions`; the actions as float32 on ``device``."""
        if isinstance(actions, np.ndarray):
            if not np.issubdtype(actions.dtype, np.number) or np.issubdtype(actions.dtype, np.complexfloating):
                raise TypeError(f"actions must be real numbers, got a numpy array of {actions.dtype}")
            actions = torch.from_numpy(np.ascontiguousarray(actions))
        if not isinstance(actions, torch.Tensor):
            raise TypeError(f"actions must be a torch.Tensor or numpy array, got {type(actions).__name__}")
        if actions.dtype == torch.bool or actions.is_complex():
            raise TypeError(f"actions must be real numbers, got {actions.dtype}")
        want = (self.num_envs, self.num_actions)
        if tuple(actions.shape) != want:
            raise ValueError(f"actions must have shape {want} (num_envs, num_actions), got {tuple(actions.shape)}")
        return actions.detach().to(device=self.device, dtype=torch.float32)

    def _zero_nonfinite(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Non-finite rows replaced by zeros, and their (num_envs,) mask (:meth:`check_actions`)."""
        nonfinite = ~self.action_manager.finite_rows(actions)
        # unconditional (no `if nonfinite.any()`): a host read here would stall a GPU pipeline every step
        actions = torch.where(nonfinite[:, None], torch.zeros_like(actions), actions)
        return actions, nonfinite

    def step(self, actions: torch.Tensor | np.ndarray) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One policy step; see the module docstring. A robot whose action row is not finite gets a
        zero action this step, is terminated (``Episode_Termination/nonfinite_action``) and reset. With
        ``scene.cuda_graph`` the step is replayed from one captured graph (``envs/env_graph.py``)."""
        actions = self._device_actions(actions)
        out = self.step_body(actions) if self.graph is None else self.graph.step(actions)
        self.common_step_counter += 1
        return out

    def step_body(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """The device work of :meth:`step` on checked ``actions`` (float32 on ``device``): what a captured graph
        holds (no Python state changes, no host reads; ``envs/env_graph.py``)."""
        actions, nonfinite = self._zero_nonfinite(actions)
        self.action_manager.process(actions, finite=True, num_physics_steps=self.decimation)
        self.scene.sim.step(self.decimation)
        return self._finish_step(nonfinite)

    def graph_generation(self) -> tuple[int, int]:
        """Changes when something a captured step reads may have been replaced (``envs/env_graph.py``): by
        :meth:`reset`, :meth:`load_state_dict` or the backend (a model array made per-robot)."""
        worlds = getattr(self.scene.sim, "worlds", None)  # the Warp backends' (WarpWorlds.generation)
        return self._generation, 0 if worlds is None else worlds.generation

    def apply_action(self, raw: torch.Tensor, num_physics_steps: int, replan: bool = False, finite: bool = False):
        """Inside :meth:`step_controlled`: send a (B, 28) raw action through the action manager, run
        ``num_physics_steps`` physics steps and refresh :attr:`state`; returns it (``RobotState``). A controller that
        re-plans several times per policy step (the closed-loop MPC at 100 Hz) calls this once per plan, ``replan=True``
        after the first, so that the action manager's previous action stays the one before the policy step (the
        action-rate terms see the step's change, as for a policy). ``finite``: the caller guarantees a finite action
        (not read back to check). Raises ``RuntimeError`` outside ``step_controlled`` or past its physics steps."""
        return self._advance("apply_action", num_physics_steps, lambda: self.action_manager.process(
            raw.to(self.device), replan=replan, finite=finite, num_physics_steps=num_physics_steps))

    def apply_references(self, freq: torch.Tensor, duty: torch.Tensor, p_td_w: torch.Tensor, F_w: torch.Tensor,
                         num_physics_steps: int) -> RobotState:
        """Inside :meth:`step_controlled`: world-frame references (freq, duty (B, 4), p_td_w (B, 4, 3) [m], F_w
        (B, 4, 3) [N]) straight to the backend's ``set_references`` for ``num_physics_steps`` physics steps, for a
        controller that makes its own references (the balance controller, the model-based baseline); the action
        manager, and so the action terms of observations and rewards, do not see them. Raises as
        :meth:`apply_action`."""
        return self._advance("apply_references", num_physics_steps,
                             lambda: self.scene.sim.set_references(freq, duty, p_td_w, F_w))

    def _advance(self, caller: str, num_physics_steps: int, send: Callable[[], None]) -> RobotState:
        """Check that ``num_physics_steps`` more fit the policy step, ``send()`` the references, step, refresh."""
        if self._controlled_steps is None:
            raise RuntimeError(f"{caller} runs inside step_controlled(physics); use step(actions) otherwise")
        if not isinstance(num_physics_steps, int) or num_physics_steps < 1:
            raise ValueError(f"num_physics_steps must be an int >= 1, got {num_physics_steps!r}")
        if self._controlled_steps + num_physics_steps > self.decimation:
            raise RuntimeError(f"{caller}: {self._controlled_steps} + {num_physics_steps} physics steps exceed "
                               f"the policy step's {self.decimation} (env.decimation)")
        send()
        self.scene.sim.step(num_physics_steps)
        self._controlled_steps += num_physics_steps
        self.refresh_state()
        return self._state

    def step_controlled(self, physics: Callable[[], torch.Tensor | None]) -> tuple[TensorDict, torch.Tensor,
                                                                                   torch.Tensor, dict]:
        """One policy step whose physics a closed-loop controller runs itself.

        ``physics()`` must advance the simulator by exactly ``decimation`` physics steps through
        :meth:`apply_action` (so the observation's last action, the action rewards and the touch-down heights
        see what was applied) -- e.g. a sampling MPC that re-plans at 100 Hz, twice per 50 Hz policy step
        (``dls_quadruped.closed_loop``) -- or :meth:`apply_references`. It may return a (B,) bool mask of robots
        that had no finite action (terminated as ``nonfinite_action``, as in :meth:`step`). Steps 3-7 of the
        module docstring follow unchanged.

        Raises:
            RuntimeError: ``physics()`` ran another number of physics steps than ``decimation``.
        """
        self._controlled_steps = 0
        try:
            nonfinite = physics()
            steps = self._controlled_steps
        finally:
            self._controlled_steps = None
        if steps != self.decimation:
            raise RuntimeError(f"step_controlled: physics() ran {steps} physics steps through apply_action, "
                               f"a policy step has {self.decimation} (env.decimation)")
        if nonfinite is None:
            nonfinite = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        out = self._finish_step(nonfinite.to(self.device))
        self.common_step_counter += 1
        return out

    def _finish_step(self, nonfinite: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Steps 3-7 of the module docstring, after the physics of a policy step."""
        self.refresh_state()
        self.episode_length_buf += 1
        self.command_manager.integrate(self.step_dt)
        self._vel_err_sum += torch.linalg.vector_norm(
            obs_mdp.base_lin_vel(self)[:, :2] - self.command_manager.command[:, :2], dim=-1)
        dones = self.termination_manager.compute(nonfinite)
        reward = self.reward_manager.compute(self.step_dt)
        time_outs = self.termination_manager.time_outs.clone()
        self.episode_log.add(self._reset(dones), dones.any())
        self.command_manager.compute(self.step_dt)
        self.event_manager.apply("interval", dt=self.step_dt)
        self.refresh_state()
        self.obs_buf = self.observation_manager.compute()
        self.extras = {"time_outs": time_outs, "log": {}}  # log: the episode values are in episode_log
        return self.obs_buf, reward, dones.long(), self.extras

    def reset(self, seed: int | None = None, episode_keys: torch.Tensor | None = None) -> tuple[TensorDict, dict]:
        """Reset every env (gymnasium-style); returns (obs, extras).

        Args:
            seed: restart the episode schedule (``envs/schedule.py``) with this seed: env i then plays
                episode 0 of key ``episode_keys[i]``, then 1, 2, ... after its own resets; the same
                (seed, key) gives the same commands, events, tile and observation noise to any policy
                or controller (the env is then as if built with this seed, curriculum state aside).
                None: go on with the schedule (every env starts its next episode).
            episode_keys: (num_envs,) non-negative integer keys (default ``arange(num_envs)``); only
                with ``seed``. K policies on the same E episodes in one env: ``arange(K * E) % E``.
        """
        if seed is not None:
            self.seed = int(seed)
            self.schedule.restart(self.seed, episode_keys)
            self.scene.assign_tiles()
            self.event_manager.apply("startup")  # per-robot model values follow the key too
        elif episode_keys is not None:
            raise ValueError("episode_keys needs a seed: reset(seed=..., episode_keys=...)")
        self._generation += 1
        self.extras = {"log": self._reset(self._every_env, curriculum=seed is None)}
        self.obs_buf = self.observation_manager.compute()
        return self.obs_buf, self.extras

    def _reset(self, env_mask: torch.Tensor, curriculum: bool = True) -> dict[str, torch.Tensor]:
        """Start the next episode of the envs of ``env_mask`` (B,) bool (step 5 of the module docstring; every row
        computed, the masked ones kept); returns the episode values of the envs that ended (0-dim tensors)."""
        log: dict[str, torch.Tensor] = {}
        self.schedule.start_episodes(env_mask)
        if curriculum:
            log.update(self.curriculum_manager.compute(env_mask))
        self.event_manager.apply("reset", env_mask)
        self.refresh_state()
        log.update(self._reset_bookkeeping(env_mask))
        return log

    @fused_method("env reset bookkeeping", eager_first=True)
    def _reset_bookkeeping(self, env_mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """The managers' resets (logged episode sums, counts; commands resampled), the env's metric and counters."""
        log: dict[str, torch.Tensor] = {}
        for manager in (self.reward_manager, self.termination_manager, self.action_manager, self.command_manager):
            log.update(manager.reset(env_mask))
        err = self._vel_err_sum / self.episode_length_buf.clamp(min=1)
        log["Episode_Metric/lin_vel_xy_error"] = torch.where(env_mask, err, 0.0).sum() / env_mask.sum().clamp(min=1)
        self._vel_err_sum.masked_fill_(env_mask, 0.0)  # scalar fills: no host-to-device copies
        self.episode_length_buf.masked_fill_(env_mask, 0)
        return log

    # ------------------------------------------------------------------ checkpoint state
    def state_dict(self) -> dict:
        """What training needs to continue where it stopped, saved in every checkpoint: what outlives an episode
        (curricula, reward weights, command ranges, terrain levels, the step counter, the schedule, the RNG) and the
        episodes in progress (``envs/checkpoint_state.py``)."""
        return checkpoint_state.env_state_dict(self)

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict` output, the RNG last. The episodes in progress go on where they stopped
        (bit-identically) when saved from as many robots; otherwise (another ``num_envs``, or an older checkpoint)
        every robot starts its next episode on its restored terrain level (without running the curriculum).

        Raises:
            ValueError: the state does not fit this env (other terms, other number of envs).
        """
        self._generation += 1
        if not checkpoint_state.load_env_state_dict(self, state):
            self._reset(self._every_env, curriculum=False)
            self.obs_buf = self.observation_manager.compute()
        checkpoint_state.load_rng_state(state, self.device)

    def close(self) -> None:
        self.scene.close()

    def summary(self) -> str:
        head = (f"[env] task={self.task.name} ({self.task.path}) num_envs={self.num_envs} device={self.device} "
                f"physics_dt={self.physics_dt} decimation={self.decimation} step_dt={self.step_dt} "
                f"episode={self.max_episode_length_s}s ({self.max_episode_length} steps) "
                f"terrain={self.scene.terrain_cfg.types} obs={self.obs_dims}")
        parts = [head] + [m.summary() for m in (self.observation_manager, self.action_manager, self.command_manager,
                                                 self.reward_manager, self.termination_manager, self.event_manager,
                                                 self.curriculum_manager)]
        return "\n".join(parts)
