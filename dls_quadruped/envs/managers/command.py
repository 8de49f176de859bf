"""Command manager: one velocity command (B, 3) resampled every U(resampling_time_s) seconds and at reset.

Task file::

    commands:
      base_velocity:
        func: uniform_velocity
        resampling_time_s: [10.0, 10.0]
        params: {lin_vel_x: [-1, 1], lin_vel_y: [-1, 1], ang_vel_z: [-1, 1]}

The manager also keeps the *commanded displacement* of every episode: where a robot that tracked
its commands exactly would be now, relative to where it started (world frame, (B, 2) [m]). The
command is a base-frame (v_x, v_y) with a yaw rate, so a robot that obeys (v, omega) walks an arc
of radius |v| / |omega|, not a line of length |v| t; the terrain curriculum compares the distance
walked with this displacement.
"""

from __future__ import annotations

import copy
from typing import Any

import torch

from dls_quadruped.core.compile import fused_method
from dls_quadruped.core.rotations import yaw_from_quat
from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import (
    ManagerBase,
    Term,
    format_table,
    resolve_terms,
)
from dls_quadruped.envs.mdp import commands as cmd_mdp


def _is_range(value: Any) -> bool:
    """A ``[low, high]`` parameter (two numbers)."""
    return (isinstance(value, (list, tuple)) and len(value) == 2
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value))


def resolve_command(task: TaskConfig) -> Term:
    """The ``commands`` section checked and resolved: exactly one term; ``resampling_time_s`` ordered, >= 0."""
    terms = resolve_terms(task, "commands", cmd_mdp, {"resampling_time_s": [10.0, 10.0]},
                          positional=("env", "env_ids"))
    if len(terms) != 1:
        raise task.error("commands", f"exactly one command term is supported, got {[t.name for t in terms]}")
    return terms[0]


class CommandManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.term = resolve_command(task)
        self.params = self.term.params  # mutable: curricula widen the ranges
        self.resampling_time_s = tuple(float(x) for x in self.term.extra["resampling_time_s"])
        self.command = torch.zeros(env.num_envs, 3, device=env.device)
        self.time_left = torch.zeros(env.num_envs, device=env.device)
        self.commanded_disp = torch.zeros(env.num_envs, 2, device=env.device)
        """(B, 2) [m] world-frame displacement of an exact tracker since the episode began."""
        self.commanded_yaw = torch.zeros(env.num_envs, device=env.device)
        """(B,) [rad] that tracker's heading (the robot's at reset, then the integrated yaw rate)."""
        self._all_ids = torch.arange(env.num_envs, device=env.device)
        # the [low, high] ranges as float64 device tensors the (compiled) samplers read: a curriculum that widens a
        # range writes into them (sync_ranges) instead of changing a Python value the compiled code was traced with
        self._ranges = {k: torch.tensor([float(x) for x in v], dtype=torch.float64, device=env.device)
                        for k, v in self.params.items() if _is_range(v)}
        self._range_values = {k: tuple(float(x) for x in self.params[k]) for k in self._ranges}

    def sync_ranges(self) -> None:
        """Copy ranges changed in ``params`` (by a curriculum, a checkpoint) into their device tensors: compares
        Python values, uploads only a changed range. Called outside the compiled functions."""
        for k, t in self._ranges.items():
            value = tuple(float(x) for x in self.params[k])
            if value != self._range_values[k]:
                t.copy_(torch.tensor(value, dtype=torch.float64))
                self._range_values[k] = value

    def range(self, name: str) -> torch.Tensor:
        """The (2,) float64 device tensor of the ``[low, high]`` parameter ``name`` the samplers read; a curriculum
        writes into it on the device (``params`` catches up in :meth:`read_ranges`, when a checkpoint is saved)."""
        return self._ranges[name]

    def read_ranges(self) -> None:
        """Copy the device ranges back into ``params`` (one host read; for a checkpoint, not for the step), after
        uploading what was written into ``params`` since the last sync (:meth:`sync_ranges`)."""
        if not self._ranges:
            return
        self.sync_ranges()
        values = torch.stack(list(self._ranges.values())).tolist()
        for k, v in zip(self._ranges, values):
            self.params[k] = [float(x) for x in v]
            self._range_values[k] = tuple(float(x) for x in v)

    def _sampler_params(self) -> dict[str, Any]:
        return {k: self._ranges.get(k, v) for k, v in self.params.items()}

    def compute(self, dt: float) -> None:
        """Advance the timers by the policy step and resample the expired commands.

        Masked, without reading on the host which expired (:meth:`_resample_where`). Compiled with
        ``scene.compile``; the ranges are device tensors, so a curriculum widening one does not recompile it."""
        self.sync_ranges()
        self._compute(dt)

    @fused_method("CommandManager.compute")
    def _compute(self, dt: float) -> None:
        self.time_left -= dt
        self._resample_where(self.time_left <= 0.0)

    def _resample_where(self, env_mask: torch.Tensor) -> None:
        """New commands and resampling times for the envs of ``env_mask`` (B,) bool: every env draws, only the masked
        ones keep their draws and advance their schedule streams (``EpisodeSchedule.only``), so the numbers are those
        of resampling the masked envs alone."""
        ids = self._all_ids
        with self.env.schedule.only(env_mask):
            command = self.term.func(self.env, ids, **self._sampler_params()).to(self.command)
            lo, hi = self.resampling_time_s
            time_left = self.env.schedule.uniform(ids, (), lo, hi, stream="command_time")
        self.command.copy_(torch.where(env_mask[:, None], command, self.command))
        self.time_left.copy_(torch.where(env_mask, time_left, self.time_left))

    def integrate(self, dt: float) -> None:
        """Advance the exact tracker by one policy step of the current command: heading by
        omega dt, position by the base-frame velocity rotated by the mid-step heading."""
        self._integrate(dt)

    @fused_method("CommandManager.integrate")
    def _integrate(self, dt: float) -> None:
        v, omega = self.command[:, :2], self.command[:, 2]
        mid = self.commanded_yaw + 0.5 * dt * omega
        c, s = torch.cos(mid), torch.sin(mid)
        self.commanded_disp += dt * torch.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], dim=-1)
        self.commanded_yaw += dt * omega

    def reset(self, env_mask: torch.Tensor) -> dict[str, float]:
        """Resample the commands of the envs of ``env_mask`` (B,) bool and restart their tracker at the robot's (reset)
        heading."""
        self._resample_where(env_mask)
        self.commanded_disp.masked_fill_(env_mask[:, None], 0.0)
        yaw = yaw_from_quat(self.env.state.base_quat_w).to(self.commanded_yaw)
        self.commanded_yaw.copy_(torch.where(env_mask, yaw, self.commanded_yaw))
        return {}

    def state_dict(self) -> dict[str, Any]:
        """``{"params": {name: value}}``: the command term's parameters (ranges) as a curriculum left them."""
        self.read_ranges()
        return {"params": copy.deepcopy(self.params)}

    def check_state_dict(self, state: dict[str, Any]) -> None:
        if set(state["params"]) != set(self.params):
            raise ValueError(f"checkpoint command parameters {sorted(state['params'])} != task's {sorted(self.params)}")

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.check_state_dict(state)
        self.read_ranges()  # where a curriculum left the device ranges: sync_ranges then uploads what differs
        self.params.clear()
        self.params.update(copy.deepcopy(state["params"]))  # in place: the term holds this dict
        self.sync_ranges()

    def summary(self) -> str:
        return format_table("commands", ("term", "function", "resampling_time_s", "params"),
                            [(self.term.name, self.term.func.__name__, self.resampling_time_s, self.params)])
