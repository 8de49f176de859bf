"""Action manager: the latent action (f, d, p, F) of thesis 4.2.2 (Tables 1 and 5).

Raw (B, 28) network output -> ``control.latent_action.ActionInterface`` (normalise, clip, frame H ->
world, touch-down z from the terrain's exact height lookup) -> the simulator backend's ``set_references``.
Task file: ``actions: {latent: {<LatentActionConfig field>: value, ...}}``.

With ``actions.horizon: {p, F, horizon, constrained_fit, dt}`` the policy acts in the sampling MPC's horizon
space instead: its (B, D) output is an encoded horizon of latent actions in raw units (``mpc.encodings``, a
distilled student's output space), the env applies its first action (``mpc.horizon.first_raw_action``: step 0 of
the MPC's decoding) as above, and the manager keeps the horizon (``raw_horizon``) with the robot state and
command it was chosen at (``decision_state``, ``decision_command``) for the terms that score it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from dls_quadruped.control.gait import contact_sequence
from dls_quadruped.control.latent_action import (
    ACTION_DIM,
    RAW_LIMIT,
    ActionInterface,
    LatentActionConfig,
    finite_entries,
    validate_raw,
)
from dls_quadruped.core.compile import fused_method
from dls_quadruped.core.rotations import yaw_from_quat
from dls_quadruped.core.state import RobotState
from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import ManagerBase, format_table
from dls_quadruped.envs.value_checks import dataclass_from_dict
from dls_quadruped.mpc import horizon as mpc_horizon

if TYPE_CHECKING:
    from dls_quadruped.mpc.config import EncodingConfig

HORIZON_KEYS = ("p", "F", "horizon", "constrained_fit", "dt")


def resolve_action_config(task: TaskConfig) -> LatentActionConfig:
    """The ``actions`` section checked: only ``latent``, with ``LatentActionConfig`` fields."""
    section = task.section("actions")
    unknown = sorted(set(section) - {"latent", "horizon"})
    if unknown:
        raise task.error(f"actions.{unknown[0]}", "unknown action term; allowed: ['horizon', 'latent']")
    resolve_horizon_config(task)  # checked with the rest of the section when the task is loaded
    return dataclass_from_dict(LatentActionConfig, section.get("latent") or {}, task, "actions.latent")


def resolve_horizon_config(task: TaskConfig) -> tuple[EncodingConfig, float] | None:
    """``actions.horizon`` checked: (the encoding, its spacing dt [s]), or None when the policy acts with one
    latent action. Defaults: the students' first-spline, H = 10, dt = 0.02 s, constrained fit."""
    spec = task.section("actions").get("horizon")
    if spec is None:
        return None
    if not isinstance(spec, dict):
        raise task.error("actions.horizon", f"must be a mapping with keys {list(HORIZON_KEYS)}, got {spec!r}")
    unknown = sorted(set(spec) - set(HORIZON_KEYS))
    if unknown:
        raise task.error(f"actions.horizon.{unknown[0]}", f"unknown key; allowed: {list(HORIZON_KEYS)}")
    dt = spec.get("dt", 0.02)
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not 0 < dt < 1:
        raise task.error("actions.horizon.dt", f"must be a number of seconds in (0, 1), got {dt!r}")
    try:
        enc = mpc_horizon.EncodingConfig(spec.get("p", "first"), spec.get("F", "spline"), spec.get("horizon", 10),
                             spec.get("constrained_fit", True))
    except ValueError as err:
        raise task.error("actions.horizon", str(err)) from None
    return enc, float(dt)


class ActionManager(ManagerBase):
    """Holds the raw, previous raw, applied (network units) and applied physical actions, (B, 28) each.

    Also, of the last processed action (training diagnostics, ``learning/diagnostics.py``): ``saturated``
    (B, 28) bool, True where the Table 1 / friction-cone clip changed the entry; ``stance_frac`` (B, 4), the
    fraction of the physics steps the action was held for in which each leg was in stance (the low-level
    controller ignores a stance leg's foothold p and a swinging leg's force F). Both are skipped while
    ``record_diagnostics`` is False (``bench/ppo_update.py`` times the iteration without them).
    """

    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.cfg = resolve_action_config(task)
        self.interface = ActionInterface(self.cfg, env.scene.terrain.height_at)
        n, dev = env.num_envs, env.device
        self.num_actions = ACTION_DIM
        horizon = resolve_horizon_config(task)
        self.horizon: EncodingConfig | None = None if horizon is None else horizon[0]
        self.horizon_dt: float | None = None if horizon is None else horizon[1]
        if self.horizon is not None:
            self.num_actions = mpc_horizon.encoded_dim(self.horizon)
            self.raw_horizon = torch.zeros(n, self.num_actions, device=dev)
            self.decision_command = torch.zeros(n, 3, device=dev)
            self.decision_state: RobotState | None = None
        self.raw_action = torch.zeros(n, ACTION_DIM, device=dev)
        self.prev_raw_action = torch.zeros_like(self.raw_action)
        self.applied_action = torch.zeros_like(self.raw_action)
        self.violation = torch.zeros_like(self.raw_action)
        self.applied_physical = torch.zeros_like(self.raw_action)
        self.saturated = torch.zeros(n, ACTION_DIM, dtype=torch.bool, device=dev)
        self.stance_frac = torch.ones(n, 4, device=dev)
        self.record_diagnostics = True

    def process(self, raw: torch.Tensor, replan: bool = False, finite: bool = False,
                num_physics_steps: int | None = None) -> None:
        """Convert and send the references to the simulator (held until the next call).

        ``replan``: a second action within the same policy step (``LocomotionEnv.apply_action``): the previous
        action stays the one before the policy step. ``finite``: ``raw`` is known to be finite
        (``LocomotionEnv.check_actions`` replaced the rows that were not, :meth:`finite_rows`), so it is not read
        back to check; otherwise a non-finite entry raises before any buffer changes. ``num_physics_steps``: how
        many physics steps the action will be held for (None: ``env.decimation``); sets ``stance_frac``.

        The raw action is kept clamped to +-``RAW_LIMIT``, so the action rate, the violation and the applied action
        of an entry of 1e20 are those of 1e6 (finite), not an overflow."""
        raw = raw.to(self.raw_action)
        if self.horizon is not None:
            raw = self._first_of_horizon(raw, replan, finite)
        if not finite:
            validate_raw(raw, cfg=self.cfg)
        if not replan:
            self.prev_raw_action[:] = self.raw_action
        self.raw_action[:] = raw.clamp(-RAW_LIMIT, RAW_LIMIT)
        f, d, p_td_w, F_w = self._convert(self.env.state)
        if self.record_diagnostics:
            self.saturated[:] = self.violation != 0
            # the gait generator's contacts over the coming physics steps, from the current phase and the new f, d
            steps = self.env.decimation if num_physics_steps is None else num_physics_steps
            _, contact = contact_sequence(self.env.state.phase.to(f), f, d, self.env.physics_dt, steps)  # (B, N, 4)
            self.stance_frac[:] = contact.to(self.stance_frac.dtype).mean(dim=-2)
        self.env.scene.sim.set_references(f, d, p_td_w, F_w)

    def _first_of_horizon(self, raw: torch.Tensor, replan: bool, finite: bool) -> torch.Tensor:
        """Keep the (B, D) horizon, and the state and command it was chosen at; return its (B, 28) first action."""
        if raw.dim() != 2 or raw.shape[1] != self.num_actions:
            raise ValueError(f"a horizon action must have shape (B, {self.num_actions}) (actions.horizon "
                             f"{self.horizon.p}-{self.horizon.F} H={self.horizon.horizon}), got {tuple(raw.shape)}")
        if not finite and not bool(torch.isfinite(raw).all()):
            raise ValueError("the horizon action contains NaN/inf; every entry must be finite")
        self.raw_horizon[:] = raw.clamp(-RAW_LIMIT, RAW_LIMIT)
        if not replan:
            self.decision_state = self.env.state.clone()
            self.decision_command[:] = self.env.command_manager.command
        return mpc_horizon.first_raw_action(self.raw_horizon, self.horizon)

    @fused_method("ActionManager.process")
    def _convert(self, s) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The raw action in ``raw_action`` to world references (f, d, p_td_w, F_w); violation and applied actions
        written (compiled with scene.compile)."""
        num_stance = s.contact_cmd.sum(dim=-1)
        refs = self.interface(self.raw_action, num_stance, s.base_pos_w, yaw_from_quat(s.base_quat_w),
                              check_finite=False)
        self.violation[:] = refs.violation
        self.applied_action[:] = self.raw_action - refs.violation
        self.applied_physical[:] = refs.action.to_vector()
        return refs.f, refs.d, refs.p_td_w, refs.F_w

    def finite_rows(self, raw: torch.Tensor) -> torch.Tensor:
        """(B,) bool: every entry of the robot's (B, 28) raw action and its physical value is finite
        (``latent_action.finite_entries``; a horizon action: every entry, and its first action's physical value);
        on the device, no host read."""
        if self.horizon is None:
            return finite_entries(raw, self.cfg).all(dim=1)
        first = mpc_horizon.first_raw_action(raw.nan_to_num(), self.horizon)
        return torch.isfinite(raw).all(dim=1) & finite_entries(first, self.cfg).all(dim=1)

    def reset(self, env_mask: torch.Tensor) -> dict[str, float]:
        """Clear the actions of the envs of ``env_mask`` (B,) bool."""
        # saturated and stance_frac stay: they describe the action just held, read after the step's resets
        bufs = [self.raw_action, self.prev_raw_action, self.applied_action, self.violation, self.applied_physical]
        for buf in bufs + ([self.raw_horizon] if self.horizon is not None else []):
            buf.masked_fill_(env_mask[:, None], 0.0)  # a scalar fill: no host-to-device copy of the 0
        return {}

    def summary(self) -> str:
        rows = [("latent", ACTION_DIM, "LatentActionConfig")]
        if self.horizon is not None:
            rows.append(("horizon", self.num_actions, f"{self.horizon}, dt {self.horizon_dt} s"))
        return format_table("actions", ("term", "dim", "config"), rows)
