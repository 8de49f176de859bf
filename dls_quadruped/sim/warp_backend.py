"""MuJoCo Warp backend: N AlienGo robots as N worlds of one MuJoCo Warp model, with the low-level
controller in torch on the same device, and no host round trip per physics step.

Registered in ``sim/registry.py`` as ``warp-cpu`` (Warp's CPU device: correctness checks on any machine) and
``cuda`` (Warp on torch's current CUDA device); ``pip install -e .[gpu]`` installs ``mujoco-warp`` (docs/gpu.md).

Design:

* **One model, zero-copy views** (:class:`~dls_quadruped.sim.warp_worlds.WarpWorlds`): the ``mujoco.MjModel``
  the CPU backend gets (``sim/terrain.py build_scene``) as ``nworld = N`` worlds of one MuJoCo Warp model,
  per-robot model values made ``(N, ...)`` when first written; ``qpos``, ``qvel``, ``ctrl``, ``time``,
  ``xfrc_applied``, ``sensordata``, ``M`` and ``qfrc_bias`` read and written through ``warp.to_torch`` views. The
  controller's buffers, the references and the published state are torch tensors on the same device. On CUDA
  the MuJoCo Warp kernels run on torch's current stream, so torch and Warp work is ordered without
  synchronisation. Inputs on the device are checked there (``sim/warp_inputs.py``), read every ``check_every``.
* **One physics step** is MuJoCo's two-phase step: the position/velocity stages (``step1``: kinematics, collision,
  ``M``, ``qfrc_bias``, position/velocity sensors) already ran on the current state, so
  :class:`~dls_quadruped.control.torch_dynamics.TorchLegDynamics` builds the controller's leg terms from MuJoCo Warp's
  own ``M`` (CSR, its row/column pairs read from the model) and ``qfrc_bias``; the controller's torques go to
  ``ctrl``; ``step2`` (actuation, constraint solver, acceleration sensors such as the foot contact forces,
  integration) advances the state; divergence is checked in torch; ``step1`` runs on the new state. The foot-contact
  sensors are copied after the last ``step2`` of a :meth:`WarpSim.step` (``step1`` zeroes them).
* **Divergence** without a host sync: after every step, a robot with a non-finite ``qpos``/``qvel`` or ``|qvel| >
  buffers.MAX_ABS_QVEL`` is flagged ``diverged`` and frozen at the model's home keyframe with zero velocity, its clock
  stopped and its torques zero, until it is reset (the CPU backend's semantics); its published contact forces are
  zero, so no NaN reaches the state.

Differences from the CPU backend (``sim/cpu_backend.py``): float32, MuJoCo Warp's own constraint solver and
contact buffers (``nconmax``/``njmax``), terrain culling per world, leg dynamics from MuJoCo's ``M`` and bias forces
instead of Pinocchio (docs/gpu.md "What differs from the CPU backend").
"""

from __future__ import annotations

import contextlib
import functools
import warnings
from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any, Self

import mujoco
import numpy as np
import torch

from dls_quadruped.control.lowlevel import LegTerms, LowLevelController
from dls_quadruped.control.torch_dynamics import TorchLegDynamics
from dls_quadruped.core.state import RobotState
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.buffers import STATE_SPECS, contact_sensor_layout
from dls_quadruped.sim.interface import (
    SimConfig,
    reset_coordinates,
    robot_weight,
    standing_references,
)
from dls_quadruped.sim.warp_collision import ALLOCATION_OVERFLOWS, collision_stats
from dls_quadruped.sim.warp_control import PhysicsRate
from dls_quadruped.sim.warp_inputs import DeviceInputs
from dls_quadruped.sim.warp_worlds import (
    WarpWorlds,
    csr_pairs,
    warp_device_for,
)

_BOOL_FIELDS = ("base_contact", "diverged")

CHECK_EVERY = 24
"""``step`` calls between host reads (overflow, non-finite references): one PPO iteration (24 env steps)."""


class WarpSim:
    """N robots as the N worlds of one MuJoCo Warp model, controlled by the low-level controller on the device.

    Args:
        model: the scene (one AlienGo, free joint first, legs in ``constants.JOINT_NAMES`` order, the ground).
        num_envs: number of robots N.
        cfg: backend configuration (``control``, ``nconmax``, ``njmax``, ``regions``: terrain culling;
            ``num_workers`` and ``nthread`` do not apply).
        device: ``"cpu"`` (Warp's CPU device) or ``"cuda"``/``"cuda:k"``.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, cfg: SimConfig | None = None, device: str = "cpu",
                 capture: bool = True):
        cfg = SimConfig() if cfg is None else cfg
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.model = model
        self.num_envs = n = num_envs
        self.cfg = cfg
        self.physics_dt = float(model.opt.timestep)
        self.wp_device = warp_device_for(device)
        self.device = torch.device(self.wp_device)
        self._closed = False
        self.base_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
        if model.nkey < 1:
            raise ValueError("the scene needs a home keyframe (key 0): the reset pose of the CPU backend")
        # overflows are flagged per robot (warp_control.PhysicsRate.settle) and reported once (_check_overflow)
        self.worlds = w = WarpWorlds(model, n, cfg, self.wp_device, self.base_body, capture)
        self.m, self.d, self.culling, self._step1, self._step2 = w.m, w.d, w.culling, w.step1, w.step2
        self._qpos, self._qvel, self._time, self._ctrl, self._xfrc = w.qpos, w.qvel, w.time, w.ctrl, w.xfrc
        self._sensordata, self._M, self._qfrc_bias = w.sensordata, w.M, w.qfrc_bias
        self._qacc_warmstart, self._overflow = w.qacc_warmstart, w.overflow
        self._warned_overflow = False
        self.dynamics = TorchLegDynamics(model, qM_pairs=csr_pairs(model))
        self.controller = LowLevelController(n, cfg.control, dt=self.physics_dt, device=self.device, solve="cramer")
        self._sensor_slices = contact_sensor_layout(model)
        self._contact_sensors = torch.zeros_like(self._sensordata)
        dev, f64 = self.device, torch.float64
        self._key_qpos = torch.as_tensor(model.key_qpos[0], dtype=self._qpos.dtype, device=dev)
        self.command = {k: torch.zeros((n, *s), dtype=f64, device=dev)
                        for k, s in (("freq", (4,)), ("duty", (4,)), ("p_td_w", (4, 3)), ("F_w", (4, 3)))}
        self.wrench_w = torch.zeros(n, 6, dtype=self._xfrc.dtype, device=dev)
        self.diverged = torch.zeros(n, dtype=torch.bool, device=dev)
        self.inputs = DeviceInputs(n, dev)
        self.check_every = CHECK_EVERY
        self._step_calls = 0
        self._in_graph_body = False  # inside an outer capture (graph_body): the host reads wait for count_step
        self.tau = torch.zeros(n, 12, dtype=f64, device=dev)
        self.buf = {k: torch.zeros((n, *s), dtype=torch.float32, device=dev)
                    for k, s in STATE_SPECS.items() if k not in _BOOL_FIELDS}
        self.buf.update({k: torch.zeros(n, dtype=torch.bool, device=dev) for k in _BOOL_FIELDS})
        self.state = RobotState(**self.buf)
        self.rate = PhysicsRate(self, cfg.compile)
        self._standing_references(slice(None))
        # every robot at the home keyframe, as the CPU backend starts
        ids = torch.arange(n, device=dev)
        with self._scope():
            self._qpos.copy_(self._key_qpos.expand(n, -1))
            self._qvel.zero_()
            w.forward(w.torch_stream())
        self._contact_sensors.copy_(self._sensordata)
        self._terms = self._dynamics_terms()
        self.controller.reset(ids, self._terms.foot_pos_w)
        self._publish()

    # ------------------------------------------------------------------ plumbing
    @property
    def capture(self) -> bool:
        """Whether ``step`` replays captured graphs of MuJoCo Warp's phases (``sim/warp_graph.py``)."""
        return self.worlds.capture

    @capture.setter
    def capture(self, enabled: bool) -> None:
        self.worlds.capture = enabled

    def _scope(self) -> ExitStack:
        """Warp's device, and on CUDA torch's current stream, for MuJoCo Warp calls."""
        return self.worlds.scope()

    def _dynamics_terms(self) -> LegTerms:
        """The controller's leg terms at the current state (``step1`` or ``forward`` ran on it), in float64."""
        return self.rate.terms()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("the Warp simulator is closed")

    def _standing_references(self, rows: slice | torch.Tensor) -> None:
        """References of ``rows``: standing (:func:`~dls_quadruped.sim.interface.standing_references`)."""
        standing_references(self.command, rows, self.total_weight())

    def total_weight(self) -> float:
        """m g of the robot in this model [N]."""
        return robot_weight(self.model)

    # ------------------------------------------------------------------ public API
    def set_references(self, freq: Any, duty: Any, p_td_w: Any, F_w: Any) -> None:
        """World-frame latent references of every robot, held until the next call (``SimBackend``).

        Shapes are checked here; finiteness on the device, without a host read: a non-finite reference is
        remembered and raised by the next :meth:`check_inputs` (every :attr:`check_every` ``step`` calls), and
        until then it makes its robot diverge, which freezes it (no NaN is published).
        """
        n = self.num_envs
        self.rate.store_references(*(self.inputs.shaped(name, value, n, shape) for name, value, shape in (
            ("freq", freq, (4,)), ("duty", duty, (4,)), ("p_td_w", p_td_w, (4, 3)), ("F_w", F_w, (4, 3)))))

    def check_inputs(self) -> None:
        """Raise if an input checked on the device since the last check was invalid (one host read): non-finite
        references or reset/push values, row ids out of range.

        Raises:
            ValueError: naming each invalid input.
        """
        self.inputs.raise_flagged(f"within the last {self.check_every} step calls")

    def step(self, num_physics_steps: int = 1) -> RobotState:
        """Advance every robot by ``num_physics_steps`` physics steps, low-level control at each (module doc)."""
        self._check_open()
        if num_physics_steps < 1:
            raise ValueError(f"num_physics_steps must be >= 1, got {num_physics_steps}")
        torch_stream, rate = self.worlds.torch_stream(), self.rate
        with self._scope():
            self._xfrc[:, self.base_body] = self.wrench_w
            for _ in range(num_physics_steps):  # sim/warp_control.py: torch work compiled where asked
                rate.control()
                self._step2(torch_stream)
                rate.settle()
                self._step1(torch_stream)
            self._terms = rate.terms()
        if not self._in_graph_body:
            self.count_step()
        return self._publish()

    def count_step(self) -> None:
        """Count a ``step`` call; every :attr:`check_every` calls the host reads (overflow, inputs). ``step`` calls
        it, except inside :meth:`graph_body`, where the caller does after each replay (a graph runs no Python)."""
        self._step_calls += 1
        if self._step_calls % self.check_every == 0:
            self._check_overflow()
            self.check_inputs()

    @contextlib.contextmanager
    def graph_body(self, stream: Any = None) -> Iterator[None]:
        """Code run inside is captured whole (``envs/env_graph.py``): MuJoCo Warp's phases launch their kernels on
        ``stream`` (the ``wp.Stream`` of Warp's external capture; None on Warp's CPU device) instead of replaying
        their own graphs, and ``step`` leaves its bookkeeping to :meth:`count_step`."""
        self._check_open()
        self.worlds.launch_directly(stream)
        self._in_graph_body = True
        try:
            yield
        finally:
            self._in_graph_body = False
            self.worlds.end_direct()

    def _check_overflow(self) -> None:
        """Warn once when a world ran out of contact or constraint rows (one host read per ``step`` call until then);
        :meth:`warp_control.PhysicsRate.settle` already flagged those robots on the device."""
        if self._warned_overflow or not bool(((self._overflow & ALLOCATION_OVERFLOWS) != 0).any()):
            return
        self._warned_overflow = True
        warnings.warn(f"MuJoCo Warp ran out of contacts or constraint rows in some worlds (nconmax "
                      f"{self.d.naconmax // self.num_envs}, njmax {self.d.njmax} per robot): those robots are flagged "
                      "diverged and reset; raise scene.nconmax / njmax (SimConfig, docs/gpu.md)", RuntimeWarning,
                      stacklevel=3)

    def collision_stats(self) -> dict[str, float | int | str]:
        """Broadphase pair tests, contacts and constraint rows per robot at the current state
        (``sim/warp_collision.py collision_stats``; host reads, for benchmarks and sizing)."""
        self._check_open()
        return collision_stats(self.m, self.d, self.culling)

    def reset(self, env_ids: Any, base_pos_w: Any, base_quat_w: Any, joint_pos: Any, joint_vel: Any = None,
              base_lin_vel_w: Any = None, base_ang_vel_b: Any = None, phase: Any = None) -> RobotState:
        """Reset robots ``env_ids`` (velocities default to zero, phases to trot); their wrench is cleared and
        they stand until their next references (``SimBackend.reset``)."""
        self._check_open()
        mask = self.inputs.mask(env_ids)
        ids = self.inputs.ids(env_ids) if mask is None else None
        n = self.num_envs if mask is not None else len(ids)
        if n == 0:
            return self.state
        rows = functools.partial(self.inputs.rows, mask=mask)
        qpos, qvel = reset_coordinates(rows, n, base_pos_w, base_quat_w, joint_pos, joint_vel, base_lin_vel_w,
                                       base_ang_vel_b, device=self.device)
        phase = None if phase is None else rows("phase", phase, n, (4,))
        w, torch_stream = self.worlds, self.worlds.torch_stream()
        if mask is None:
            w.reset_mask.zero_()
            w.reset_mask.index_fill_(0, ids, True)  # scalar fills: x[ids] = v copies v from the host on CUDA
        else:
            w.reset_mask.copy_(mask)
        with self._scope():
            w.reset_data(torch_stream)  # captured graphs (WarpWorlds): one launch each
            if mask is None:
                self._qpos[ids] = qpos.to(self._qpos.dtype)
                self._qvel[ids] = qvel.to(self._qvel.dtype)
                self._time.index_fill_(0, ids, 0.0)
            else:  # static shapes: every row computed, the masked ones kept
                self._qpos.copy_(torch.where(mask[:, None], qpos.to(self._qpos.dtype), self._qpos))
                self._qvel.copy_(torch.where(mask[:, None], qvel.to(self._qvel.dtype), self._qvel))
                self._time.masked_fill_(mask, 0.0)
            w.forward(torch_stream)  # every stage, sensors included: the reset robots' published forces
        self._terms = self._dynamics_terms()
        # sensors, flags, references, controller
        self.rate.reset_rows(ids if mask is None else mask, self._terms.foot_pos_w, phase)
        return self._publish()

    def set_external_wrench(self, env_ids: Any, force_w: Any, torque_w: Any) -> None:
        """Constant external force [N] and torque [N m] on the base (world frame) until changed."""
        mask = self.inputs.mask(env_ids)
        ids = self.inputs.ids(env_ids) if mask is None else None
        n = self.num_envs if mask is not None else len(ids)
        wrench = torch.cat([self.inputs.rows("force_w", force_w, n, (3,), mask),
                            self.inputs.rows("torque_w", torque_w, n, (3,), mask)], dim=1).to(self.wrench_w)
        if mask is None:
            self.wrench_w[ids] = wrench
        else:
            self.wrench_w.copy_(torch.where(mask[:, None], wrench, self.wrench_w))

    def set_base_velocity(self, env_ids: Any, lin_vel_w: Any) -> RobotState:
        """Set the base linear velocity (world frame) of robots ``env_ids``: a push."""
        self._check_open()
        mask = self.inputs.mask(env_ids)
        if mask is None:
            ids = self.inputs.ids(env_ids)
            self._qvel[ids, 0:3] = self.inputs.rows("lin_vel_w", lin_vel_w, len(ids), (3,)).to(self._qvel.dtype)
        else:
            v = self.inputs.rows("lin_vel_w", lin_vel_w, self.num_envs, (3,), mask).to(self._qvel.dtype)
            self._qvel[:, 0:3] = torch.where(mask[:, None], v, self._qvel[:, 0:3])
        with self._scope():
            # the whole step1, replayed from its graph (one launch): its velocity stage alone (fwd_velocity +
            # sensor_vel) is not equivalent -- on warp-cpu it moved the pushed robot's foot forces by up to 18 N on
            # the following steps (likely the position stage's factorisation of M, which step2's implicit
            # integration leaves changed); MuJoCo Warp 4.0 has no per-world mask for step1, so every world runs it
            self._step1(self.worlds.torch_stream())
        self._terms = self._dynamics_terms()
        return self._publish()

    def set_model_field(self, name: str, env_ids: Any, values: Any, index: Any = None) -> None:
        """Per-robot model values, e.g. ``geom_friction`` (n, ngeom, 3) or, with ``index``, (n, len(index), 3);
        ``body_mass`` (n, nbody). The controller's dynamics read MuJoCo's own mass matrix, so a changed mass is
        modelled (the CPU backend's Pinocchio model stays nominal)."""
        self._check_open()
        field = self.worlds.batched_field(name)
        mask = self.inputs.mask(env_ids)
        # a mask keeps its rows of values for every robot: as ids of all robots, with the others' old values
        ids = self.inputs.ids(env_ids) if mask is None else torch.arange(self.num_envs, device=self.device)
        values = torch.as_tensor(values).to(self.device, field.dtype)
        if len(values) != len(ids):
            raise ValueError(f"values must have one row per env id ({len(ids)}), got {len(values)}")
        if index is None:
            if values.shape[1:] != field.shape[1:]:
                raise ValueError(f"{name} values must be (n, {', '.join(map(str, field.shape[1:]))}), "
                                 f"got {tuple(values.shape)}")
            at = ids
        else:
            idx = torch.as_tensor(np.asarray(index.cpu() if isinstance(index, torch.Tensor) else index),
                                  dtype=torch.long, device=self.device)
            at = (ids[:, None], idx[None, :])
        if mask is not None:
            values = torch.where(mask.view(-1, *[1] * (values.dim() - 1)), values, field[at])
        field[at] = values
        with self._scope():  # positions and the mass matrix of the new model (a mass changes M)
            self._step1(self.worlds.torch_stream())
        self._terms = self._dynamics_terms()

    def snapshot(self) -> dict:
        """The whole simulation state (MuJoCo Warp's integration state, per-robot model fields, the controller,
        divergence flags, last torques, contact sensors, published state and commands), as torch clones."""
        return {"mj": self.worlds.integration_state(), "model": self.worlds.fields_state(),
                "controller": self.controller.state_dict(), "diverged": self.diverged.clone(),
                "tau": self.tau.clone(), "contact_sensors": self._contact_sensors.clone(),
                "state": {k: v.clone() for k, v in self.buf.items()},
                "command": {**{k: v.clone() for k, v in self.command.items()}, "wrench_w": self.wrench_w.clone()}}

    def restore(self, snap: dict) -> RobotState:
        """Load :meth:`snapshot` output of a Warp backend of as many robots: the next ``step`` is bit-identical.

        Raises:
            ValueError: a snapshot of another number of robots.
        """
        self._check_open()
        n = int(snap["diverged"].shape[0])
        if n != self.num_envs:
            raise ValueError(f"simulator snapshot of {n} robots, this simulator has {self.num_envs}")
        self.worlds.load_state(snap["mj"], snap["model"])
        self.controller.load_state_dict(snap["controller"])
        self.diverged.copy_(snap["diverged"])
        self.tau.copy_(snap["tau"])
        self._contact_sensors.copy_(snap["contact_sensors"])
        for k, v in self.buf.items():
            v.copy_(snap["state"][k])
        for k, v in self.command.items():
            v.copy_(snap["command"][k])
        self.wrench_w.copy_(snap["command"]["wrench_w"])
        with self._scope():
            self._step1(self.worlds.torch_stream())
        self._terms = self._dynamics_terms()
        return self.state

    def close(self) -> None:
        """Free the device arrays (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.worlds = self.m = self.d = self._step1 = self._step2 = None
        self._qpos = self._qvel = self._time = self._ctrl = self._xfrc = None
        self._sensordata = self._M = self._qfrc_bias = self._qacc_warmstart = self._overflow = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ output
    def _publish(self) -> RobotState:
        """Write the current state into the published float32 buffers (in place: ``state`` stays live)."""
        self.rate.publish()
        return self.state
