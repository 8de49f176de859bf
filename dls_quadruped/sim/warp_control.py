"""The torch side of one physics step of the Warp backends, as three functions compiled into a few fused kernels.

Per physics step ``WarpSim.step`` (``sim/warp_backend.py``) runs::

    control()   leg terms from MuJoCo Warp's state (torch kinematics + its M, qfrc_bias), low-level controller,
                divergence flags, torques into MuJoCo Warp's ctrl
    step2       MuJoCo Warp (a captured graph on CUDA)
    settle()    robots whose state blew up (or whose world overflowed) flagged and frozen; contact sensors kept
    step1       MuJoCo Warp (a captured graph on CUDA)

and after the last physics step of a call ``terms()`` once, for the published foot state. Each of the three is a
:func:`core.compile.fused_method`: compiled with ``torch.compile`` when ``SimConfig.compile`` says so (default: on
CUDA), so a physics step is a few fused torch kernels besides MuJoCo Warp's graphs, instead of ~450 operator
launches (docs/gpu.md "Launches"). Every buffer they write is written in place (the controller's state, the
torques, ``ctrl``, the flags, the clock): the storage a compiled graph points at never moves.

Eager and compiled agree to round-off (bit for bit on warp-cpu, ``tests/sim/test_warp_control.py``); the
controller's damped 3x3 solve is the elementwise one (``LowLevelController(solve="cramer")``) on both, so the two
paths run the same arithmetic. The backend's ``set_references`` and state publishing are compiled here too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from dls_quadruped.control.lowlevel import LegTerms
from dls_quadruped.core.compile import compile_wanted, fused_method
from dls_quadruped.sim.buffers import MAX_ABS_QVEL
from dls_quadruped.sim.interface import standing_references
from dls_quadruped.sim.warp_collision import ALLOCATION_OVERFLOWS
from dls_quadruped.sim.warp_worlds import publish_contacts

if TYPE_CHECKING:
    from dls_quadruped.sim.warp_backend import WarpSim



class PhysicsRate:
    """The compiled (or eager) torch work of a :class:`WarpSim` physics step (module doc).

    Args:
        sim: the backend; its MuJoCo Warp buffers, controller, dynamics and commands are read from it.
        compile: ``SimConfig.compile`` (None: on for CUDA devices).

    Attributes:
        compile: whether the ``fused_method`` functions below are compiled (``compile`` resolved for the device).
        compiled: whether the three step functions run compiled (False after a compile failure, with a warning).
    """

    def __init__(self, sim: WarpSim, compile: bool | None = None):
        self.sim = sim
        self.compile = compile_wanted(compile, sim.device)  # each fused_method below is compiled when True
        self.time_before = torch.zeros_like(sim._time)
        self._weight_value: float | None = None  # m g the cached (1,) tensor below holds (_weight)
        self._weight_tensor: torch.Tensor | None = None
        # the dynamics' constant tensors (chain parameters, index tables) are built on first use: build them here,
        # eagerly, so the compiled functions find them made (creating them from numpy inside a trace fails)
        self._terms.fn(sim._qpos, sim._qvel, sim._M, sim._qfrc_bias)

    @property
    def compiled(self) -> bool:
        return self._control.compiled and self._settle.compiled and self._terms.compiled

    # The buffers go in as arguments (not read from self inside the compiled code), so the graphs' inputs are the
    # backend's live tensors and nothing is guarded on Python attributes.
    def control(self) -> None:
        """Torques of this physics step into ``ctrl`` (and ``sim.tau``); the controller advances its phases."""
        s, c = self.sim, self.sim.command
        self._control(s._qpos, s._qvel, s._M, s._qfrc_bias, c["freq"], c["duty"], c["p_td_w"], c["F_w"],
                      s.diverged, s.tau, s._ctrl, s._time, self.time_before)

    def settle(self) -> None:
        """After ``step2``: flag and freeze diverged robots, keep the contact sensors ``step1`` will zero."""
        s = self.sim
        self._settle(s._qpos, s._qvel, s._qacc_warmstart, s._time, self.time_before, s._overflow, s.diverged,
                     s._key_qpos, s._contact_sensors, s._sensordata)

    def terms(self) -> LegTerms:
        """The controller's leg terms at the current state (``step1`` or ``forward`` ran on it), float64."""
        s = self.sim
        return self._terms(s._qpos, s._qvel, s._M, s._qfrc_bias)

    @fused_method("WarpSim leg terms")
    def _terms(self, qpos, qvel, M, bias) -> LegTerms:
        f64 = torch.float64
        return self.sim.dynamics.terms(qpos.to(f64), qvel.to(f64), M, bias)

    @fused_method("WarpSim physics-step control")
    def _control(self, qpos, qvel, M, bias, freq, duty, p_td_w, F_w, diverged, tau_out, ctrl, time,
                 time_before) -> None:
        terms = self._terms.fn(qpos, qvel, M, bias)
        tau = self.sim.controller.compute(terms, freq, duty, p_td_w, F_w)
        diverged |= ~torch.isfinite(tau).all(dim=1)  # non-finite references (set_references)
        tau = tau.masked_fill(diverged[:, None], 0.0)
        tau_out.copy_(tau)
        ctrl.copy_(tau)
        time_before.copy_(time)

    @fused_method("WarpSim physics-step settle")
    @staticmethod
    def _settle(qpos, qvel, qacc_warmstart, time, time_before, overflow, diverged, key_qpos, contact_sensors,
                sensordata) -> None:
        # robots whose state blew up or whose world ran out of contacts or constraint rows (MuJoCo Warp dropped
        # some: the step was wrong) are flagged; every flagged robot is held at the keyframe, at rest, clock stopped
        bad = ~torch.isfinite(qpos).all(dim=1) | ~torch.isfinite(qvel).all(dim=1)
        bad |= qvel.abs().amax(dim=1) > MAX_ABS_QVEL
        bad |= (overflow & ALLOCATION_OVERFLOWS) != 0  # sticky until the robot's reset clears it
        diverged |= bad
        div = diverged[:, None]
        qpos.copy_(torch.where(div, key_qpos, qpos))
        qvel.masked_fill_(div, 0.0)
        qacc_warmstart.masked_fill_(div, 0.0)
        time.copy_(torch.where(diverged, time_before, time))
        contact_sensors.copy_(sensordata)  # step1 zeroes the acceleration-stage sensors

    def reset_rows(self, ids: torch.Tensor, foot_pos_w: torch.Tensor, phase: torch.Tensor | None) -> None:
        """After a reset's ``forward``: the robots ``ids`` (ids, or an (N,) bool mask) get their contact sensors,
        cleared flags, wrench and torques, standing references and a fresh controller (phases ``phase`` or trot,
        lift-off at ``foot_pos_w``, (N, 4, 3) of every robot)."""
        s = self.sim
        self._reset(ids, foot_pos_w, phase, self._weight(), s._contact_sensors, s._sensordata, s.diverged,
                    s.wrench_w, s.tau, s.command)

    def _weight(self) -> torch.Tensor:
        """(1,) m g, float64 on the device, uploaded once per value. Not a Python float (a symbolic input of the
        compiled reset, whose guards torch 2.11 evaluates on the host at every call), nor a 0-d tensor (on the CPU
        torch 2.11 treats one as a number and reads it back to guard against NaN)."""
        w = self.sim.total_weight()
        if self._weight_value != w:
            self._weight_value = w
            self._weight_tensor = torch.tensor([w], dtype=torch.float64, device=self.sim.device)
        return self._weight_tensor

    @fused_method("WarpSim reset rows", dynamic=True)  # a reset's robots vary
    def _reset(self, ids, foot_pos_w, phase, weight, contact_sensors, sensordata, diverged, wrench_w, tau,
               command) -> None:
        if ids.dtype == torch.bool:  # a mask (N,): static shapes, the masked rows kept
            contact_sensors.copy_(torch.where(ids[:, None], sensordata, contact_sensors))
            diverged.logical_and_(~ids)
            wrench_w.masked_fill_(ids[:, None], 0.0)
            standing_references(command, ids, weight[0])
            self.sim.controller.reset(ids, foot_pos_w, phase)
            tau.masked_fill_(ids[:, None], 0.0)
            return
        contact_sensors[ids] = sensordata[ids]
        diverged.index_fill_(0, ids, False)  # scalar fills: x[ids] = v copies v from the host on CUDA
        wrench_w.index_fill_(0, ids, 0.0)
        standing_references(command, ids, weight[0])
        self.sim.controller.reset(ids, foot_pos_w[ids], phase)
        tau.index_fill_(0, ids, 0.0)

    def store_references(self, freq, duty, p_td_w, F_w) -> None:
        """The latent references (float64, shaped) into the held commands; non-finite ones flagged on the device."""
        c = self.sim.command
        self._store(self.sim.inputs.bad_refs, (freq, duty, p_td_w, F_w), (c["freq"], c["duty"], c["p_td_w"], c["F_w"]))

    @fused_method("WarpSim set_references")
    @staticmethod
    def _store(bad_refs, values, held) -> None:
        for i, (value, dst) in enumerate(zip(values, held)):
            bad_refs[i] |= ~torch.isfinite(value).all()
            dst.copy_(value)

    def publish(self) -> None:
        """The current state into the backend's published float32 buffers (``WarpSim.state``), in place."""
        s = self.sim
        self._publish(s.buf, s._qpos, s._qvel, s.tau, s._terms.foot_pos_w, s._terms.foot_vel_w, s.diverged,
                      s._contact_sensors, s.controller.phase, s.command["duty"], s._time)

    @fused_method("WarpSim publish")
    def _publish(self, buf, qpos, qvel, tau, foot_pos_w, foot_vel_w, diverged, contact_sensors, phase, duty,
                 time) -> None:
        buf["base_pos_w"].copy_(qpos[:, 0:3])
        buf["base_quat_w"].copy_(qpos[:, 3:7])
        buf["base_lin_vel_w"].copy_(qvel[:, 0:3])
        buf["base_ang_vel_b"].copy_(qvel[:, 3:6])
        buf["joint_pos"].copy_(qpos[:, 7:19])
        buf["joint_vel"].copy_(qvel[:, 6:18])
        buf["joint_torque"].copy_(tau)
        buf["foot_pos_w"].copy_(foot_pos_w)
        buf["foot_vel_w"].copy_(foot_vel_w)
        sd = torch.where(diverged[:, None], 0.0, contact_sensors)
        publish_contacts(sd, self.sim._sensor_slices, buf["foot_force_w"], buf["base_contact"])
        buf["phase"].copy_(phase)
        buf["contact_cmd"].copy_(phase < duty)
        buf["time"].copy_(time)
        buf["diverged"].copy_(diverged)
