"""One shard of robots: a ``mujoco.batch.Batch`` + the leg dynamics + the low-level controller.

A shard runs the whole physics/control loop for a contiguous block of robots. The
backend (``sim/cpu_backend.py``) runs one shard in-process or one per worker process;
shards talk to the backend only through the shared buffers (:class:`~dls_quadruped.sim.buffers.SharedBuffers`),
so the same code serves both modes.

Per physics step (200 Hz): leg terms at the current state -> low-level torques (batched torch) ->
``Batch.step`` on the robots that are still valid. Two sources of the leg terms
(``SimConfig.leg_dynamics``):

* ``pinocchio`` (default): one Pinocchio call per robot (Pinocchio gives nothing batched), on the
  nominal robot model.
* ``mujoco``: the batch is persistent (one ``MjData`` per robot) and steps with
  ``stage=mjSTAGE_VEL``, so after each step MuJoCo's mass matrix ``M`` and bias forces ``qfrc_bias``
  are those of the new state (the position and velocity stages of the next step, which the
  persistent batch then continues from instead of recomputing them); ``TorchLegDynamics`` reads the
  leg blocks from them and adds batched torch foot kinematics. No Pinocchio call in the loop. M and
  the bias come from each robot's own model, so per-robot ``body_mass`` etc. reach the controller.
  Whenever the state or a robot's model changes outside a step (reset, restore, push, divergence,
  terrain-region switch, ``set_model_field``), ``Batch.forward(ids, stage=mjSTAGE_VEL)`` recomputes
  those stages first, so no step and no term uses stale M/bias. The stepped state is bit-identical
  to the default path's given the same torques; the position-stage sensors (contact flags), which
  ``stage=mjSTAGE_VEL`` moves to the new state, are published one substep behind as ``mj_step``
  leaves them, so the published state matches the default path too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch
from mujoco.batch import Batch, SimulationError

from dls_quadruped.control.lowlevel import LegTerms, LowLevelConfig, LowLevelController
from dls_quadruped.control.torch_dynamics import TorchLegDynamics
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.buffers import MAX_ABS_QVEL, SharedBuffers, contact_sensor_layout
from dls_quadruped.sim.regions import RegionConfig, RobotRegions

if TYPE_CHECKING:
    from dls_quadruped.control.dynamics import LegDynamics

MJ_STATE_FIELDS = ("time", "qpos", "qvel", "act", "history", "qacc_warmstart", "plugin_state", "ctrl",
                   "qfrc_applied", "xfrc_applied", "eq_active", "mocap_pos", "mocap_quat", "userdata")
"""MjData fields of ``mjSTATE_INTEGRATION``: everything ``mj_step`` reads that it did not compute itself
(``qacc_warmstart`` included: the constraint solver starts from it, so a restored run that lacked
it would differ in the last bits)."""


class Shard:
    """Simulates robots [start, stop) of the backend.

    Args:
        model: MuJoCo model containing one AlienGo (names from ``constants``).
        buffers: the rows of the shared buffers that belong to this shard.
        ctrl_cfg: low-level controller configuration.
        nthread: threads of this shard's ``Batch`` (1 in a worker process).
        regions: run each robot on the region model of the terrain cell it is in (``sim/regions.py``);
            None runs every robot on ``model``.
        leg_dynamics: ``pinocchio`` or ``mujoco`` (``SimConfig.leg_dynamics``, the module doc).
    """

    def __init__(self, model: mujoco.MjModel, buffers: SharedBuffers, ctrl_cfg: LowLevelConfig, nthread: int,
                 regions: RegionConfig | None = None, leg_dynamics: str = "pinocchio"):
        if leg_dynamics not in ("pinocchio", "mujoco"):
            raise ValueError(f"unknown leg_dynamics {leg_dynamics!r}; allowed: pinocchio, mujoco")
        self.model = model
        self.buf = buffers
        n = buffers.state["time"].shape[0]
        self.n = n
        self.mujoco_terms = leg_dynamics == "mujoco"
        self.regions = RobotRegions(regions.build(model), model, n) if regions is not None else None
        self.batch = Batch(model if self.regions is None else self.regions.models[0], n, nthread=nthread,
                           persistent=self.mujoco_terms)
        self._step_stage = mujoco.mjtStage.mjSTAGE_VEL if self.mujoco_terms else mujoco.mjtStage.mjSTAGE_NONE
        self.qpos = self.batch.bind("qpos")
        self.qvel = self.batch.bind("qvel")
        self.ctrl = self.batch.bind("ctrl")
        self.time = self.batch.bind("time")
        self.xfrc = self.batch.bind("xfrc_applied")
        self.sensordata = self.batch.bind("sensordata")
        if self.mujoco_terms:
            self.dynamics: TorchLegDynamics | LegDynamics = TorchLegDynamics(model)
            self._M = self.batch.bind("M")  # MuJoCo 4's sparse inertia (data.M)
            self._bias = self.batch.bind("qfrc_bias")
            self._qM_adr = self.dynamics.qM_adr  # (4, 3, 3) leg-block addresses in M
            self._leg_dof = self.dynamics.params.dof_adr  # (4, 3)
            # position/velocity-stage sensors (contact flags): published one substep behind, as mj_step leaves them
            stage = model.sensor_needstage
            cols = [np.arange(model.sensor_adr[i], model.sensor_adr[i] + model.sensor_dim[i])
                    for i in range(model.nsensor) if stage[i] < int(mujoco.mjtStage.mjSTAGE_ACC)]
            self._lagged_cols = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
        else:
            # Pinocchio is imported here, not at the top: only this path calls it, and a machine that runs the
            # Warp backends alone may not have `pin`
            from dls_quadruped.control.dynamics import LegDynamics

            self.dynamics = LegDynamics(model_path=C.MJCF_PATH)
        self.controller = LowLevelController(n, ctrl_cfg, dt=model.opt.timestep)
        self.base_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
        self.joint_qpos_adr = self._joint_adr(model)
        self._sensor_slices = contact_sensor_layout(model)
        self.diverged = np.zeros(n, dtype=bool)
        self.tau = torch.zeros(n, 12, dtype=torch.float64)
        self._update_regions(forward=False)  # the reset's mj_forward follows
        self.batch.reset(keyframe=np.zeros(n, dtype=np.int32))
        if self._update_regions(forward=False):  # the keyframe's base is in another cell than qpos0's
            self.batch.forward()
        # mujoco path: the sensor values publish() shows (the batch's, lagged columns one substep behind)
        self._sensors = np.array(self.sensordata) if self.mujoco_terms else None
        self._terms = self._dynamics_terms()
        self.controller.reset(torch.arange(n), self._terms.foot_pos_w)
        self.publish()

    # ------------------------------------------------------------------ layout
    @staticmethod
    def _joint_adr(model: mujoco.MjModel) -> np.ndarray:
        """qpos addresses of the 12 leg joints in constants.JOINT_NAMES order (must be 7..18)."""
        adr = np.array([model.jnt_qposadr[model.joint(name).id] for name in C.JOINT_NAMES])
        if not np.array_equal(adr, np.arange(7, 19)) or model.nq != 19 or model.nv != 18:
            raise ValueError(
                "the scene must contain exactly one AlienGo with its free joint first and legs in "
                f"{C.JOINT_NAMES} order (qpos addresses 7..18); got nq={model.nq}, addresses {adr.tolist()}"
            )
        return adr

    # ------------------------------------------------------------------ stepping
    def _update_regions(self, forward: bool = True) -> bool:
        """With terrain regions: every robot on the region model of its base's cell (``sim/regions.py``);
        True if a model changed. Called before every physics step and after every state write. On the
        mujoco path the robots that changed model get their position/velocity stages recomputed on it
        (the persistent batch would otherwise continue from contacts found on the old model)."""
        if self.regions is None:
            return False
        before = self.regions.cell.copy() if self.mujoco_terms else None
        if not self.regions.update(self.qpos[:, 0], self.qpos[:, 1]):
            return False
        self.batch.set_models(self.regions.models)
        if self.mujoco_terms and forward:
            self._forward_vel(np.flatnonzero(self.regions.cell != before))
        return True

    def _forward_vel(self, ids: np.ndarray | None = None) -> None:
        """mujoco path: recompute the position and velocity stages (M, qfrc_bias, contacts) of robots ``ids``
        (None: all) at their current state and model, after a write that a step did not make. Robots MuJoCo
        refuses are marked diverged."""
        if ids is not None and len(ids) == 0:
            return
        try:
            self.batch.forward(ids=ids, stage=mujoco.mjtStage.mjSTAGE_VEL)
        except SimulationError as err:
            self.diverged[err.ids if ids is None else ids[err.ids]] = True

    def _dynamics_terms(self) -> LegTerms:
        f = torch.from_numpy
        if self.mujoco_terms:
            # M and qfrc_bias are those of the current state (step(stage=mjSTAGE_VEL) or _forward_vel);
            # fancy indexing copies the read-only outputs' leg entries into writable arrays for torch
            kin = self.dynamics.kinematics(f(self.qpos), f(self.qvel))
            return LegTerms(M_leg=f(self._M[:, self._qM_adr]), h_leg=f(self._bias[:, self._leg_dof]),
                            J_leg=kin.J_leg, Jdot_qdot=kin.Jdot_qdot, foot_pos_w=kin.foot_pos_w,
                            foot_vel_w=kin.foot_vel_w)
        d = self.dynamics.compute(self.qpos, self.qvel)
        return LegTerms(f(d.M_leg), f(d.h_leg), f(d.J_leg), f(d.Jdot_qdot), f(d.foot_pos_w), f(d.foot_vel_w))

    def step(self, num_steps: int) -> None:
        """Run ``num_steps`` physics steps with low-level control at every step."""
        cmd = self.buf.command
        freq, duty, p_td_w, F_w = cmd["freq"], cmd["duty"], cmd["p_td_w"], cmd["F_w"]
        self.xfrc[:, self.base_body, :] = cmd["wrench_w"].numpy()
        for _ in range(num_steps):
            terms = self._terms
            self.tau = self.controller.compute(terms, freq, duty, p_td_w, F_w)
            tau = self.tau.numpy()
            tau[self.diverged] = 0.0
            self.ctrl[:] = tau
            alive = np.flatnonzero(~self.diverged)
            if len(alive) == 0:
                break
            self._update_regions()
            if self.mujoco_terms:
                lagged = self.sensordata[:, self._lagged_cols]  # at the state before this step (a copy)
            try:
                self.batch.step(ids=alive if len(alive) < self.n else None, stage=self._step_stage)
            except SimulationError as err:
                failed = err.ids if len(alive) == self.n else alive[err.ids]
                self.diverged[failed] = True
                if self.mujoco_terms:  # their derived fields are not of their (kept) state
                    self._forward_vel(np.sort(failed))
            if self.mujoco_terms:
                self._sensors[:] = self.sensordata
                self._sensors[:, self._lagged_cols] = lagged
            self._check_divergence()
            self._terms = self._dynamics_terms()
        self.publish()

    def _check_divergence(self) -> None:
        bad = ~np.isfinite(self.qpos).all(axis=1) | ~np.isfinite(self.qvel).all(axis=1)
        bad |= np.abs(self.qvel).max(axis=1) > MAX_ABS_QVEL
        if bad.any():
            self.diverged |= bad
            # keep the arrays finite so the leg terms and the controller stay well defined
            self.qpos[bad] = self.model.key_qpos[0]
            self.qvel[bad] = 0.0
            if self.mujoco_terms:
                self._forward_vel(np.flatnonzero(bad))

    # ------------------------------------------------------------------ commands
    def reset(self, ids: np.ndarray) -> None:
        """Reset robots ``ids`` (shard-local) to the states in the reset command buffers."""
        if len(ids) == 0:
            return
        cmd = self.buf.command
        self.batch.reset(ids=ids, keyframe=np.zeros(len(ids), dtype=np.int32), stage=mujoco.mjtStage.mjSTAGE_NONE)
        self.qpos[ids] = cmd["reset_qpos"][ids].numpy()
        self.qvel[ids] = cmd["reset_qvel"][ids].numpy()
        self.time[ids] = 0.0
        self._update_regions()
        self.batch.forward(ids=ids)  # mj_forward: M and qfrc_bias of the new state for the mujoco path too
        self.diverged[ids] = False
        if self.mujoco_terms:
            self._sensors[ids] = self.sensordata[ids]
        self._terms = self._dynamics_terms()
        tids = torch.from_numpy(ids)
        self.controller.reset(tids, self._terms.foot_pos_w[tids], cmd["reset_phase"][tids])
        self.tau[tids] = 0.0
        self.publish()

    def set_lin_vel(self, ids: np.ndarray) -> None:
        """Override the base linear velocity (world frame) of robots ``ids`` (pushes)."""
        self.qvel[ids, 0:3] = self.buf.command["set_lin_vel_w"][ids].numpy()
        if self.mujoco_terms:
            self._forward_vel(np.sort(np.asarray(ids)))
        self._terms = self._dynamics_terms()
        self.publish()

    def set_model_field(self, key: str | tuple[str, np.ndarray | None], ids: np.ndarray, values: np.ndarray) -> None:
        """Per-robot model values (randomisation) through ``Batch.expand``. With ``leg_dynamics="pinocchio"`` the
        controller keeps the nominal model; with ``"mujoco"`` its M and bias follow the robot's model (the
        stages of ``ids`` are recomputed here, and their terms with them).

        ``key`` is the field name, or ``(name, index)`` to write only the rows ``index`` of the
        field's first dimension (e.g. four foot geoms of ``geom_friction``): ``values`` is then
        ``(len(ids), len(index), ...)``.
        """
        name, index = key if isinstance(key, tuple) else (key, None)
        if self.regions is not None:  # Batch.expand is refused beside caller models: per-robot model copies
            self.regions.set_field(name, ids, index, values)
            self.batch.set_models(self.regions.models)
        else:
            field = self.batch.expand(name)
            if index is None:
                field[ids] = values
            else:
                field[np.ix_(ids, index)] = values
        if self.mujoco_terms:
            self._forward_vel(np.unique(np.asarray(ids)))
            self._terms = self._dynamics_terms()

    def robot_model_field(self, name: str) -> np.ndarray | None:
        """(n, ...) per-robot values of a model field in ``model``'s layout (None: never set per robot
        without regions)."""
        return self.batch.expanded(name) if self.regions is None else self.regions.field(name)

    # ------------------------------------------------------------------ checkpoints
    def snapshot(self) -> dict:
        """This shard's whole simulation state (rows = its robots): the MuJoCo integration state, the
        controller's buffers, the divergence flags and the last torques. Restored with :meth:`restore`,
        the next :meth:`step` is bit-identical to the one the snapshot's shard would have taken."""
        mj = {f: np.array(self.batch.bind(f), copy=True) for f in MJ_STATE_FIELDS}
        size = sum(v[0].size for v in mj.values()) if self.n else 0
        if self.n and size != self.batch.nstate:  # a MuJoCo with more state than MJ_STATE_FIELDS names
            raise RuntimeError(f"MJ_STATE_FIELDS hold {size} numbers per robot, MuJoCo's state has {self.batch.nstate}")
        return {"mj": mj, "controller": self.controller.state_dict(), "diverged": self.diverged.copy(),
                "tau": self.tau.clone()}

    def restore(self, snap: dict) -> None:
        """Load :meth:`snapshot` output (of as many robots as this shard has); the published buffers are
        the backend's to restore (the last step's sensor outputs are not recomputed here).

        Raises:
            ValueError: another number of robots.
        """
        if len(snap["diverged"]) != self.n:
            raise ValueError(f"simulator snapshot of {len(snap['diverged'])} robots for a shard of {self.n}")
        for f in MJ_STATE_FIELDS:
            self.batch.bind(f)[:] = snap["mj"][f]
        self.controller.load_state_dict(snap["controller"])
        self.diverged[:] = snap["diverged"]
        self.tau = snap["tau"].clone()
        self._update_regions()
        if self.mujoco_terms:  # M, qfrc_bias and contacts of the restored state and models, as a step leaves them
            self._forward_vel()
        # a pure function of (qpos, qvel) (and the models: mujoco), as after a step
        self._terms = self._dynamics_terms()

    # ------------------------------------------------------------------ output
    def publish(self) -> None:
        """Write the current state into the shared float32 state buffers."""
        s = self.buf.state
        qpos, qvel = self.qpos, self.qvel
        s["base_pos_w"][:] = torch.from_numpy(qpos[:, 0:3])
        s["base_quat_w"][:] = torch.from_numpy(qpos[:, 3:7])
        s["base_lin_vel_w"][:] = torch.from_numpy(qvel[:, 0:3])
        s["base_ang_vel_b"][:] = torch.from_numpy(qvel[:, 3:6])
        s["joint_pos"][:] = torch.from_numpy(qpos[:, 7:19])
        s["joint_vel"][:] = torch.from_numpy(qvel[:, 6:18])
        s["joint_torque"][:] = self.tau
        s["foot_pos_w"][:] = self._terms.foot_pos_w
        s["foot_vel_w"][:] = self._terms.foot_vel_w
        sd = self.sensordata if self._sensors is None else self._sensors
        for i, leg in enumerate(C.LEG_NAMES):
            # the netforce sensor reports the foot's force on the ground: negate for the reaction
            sl = self._sensor_slices[f"{leg}_foot_contact"]
            s["foot_force_w"][:, i] = -torch.from_numpy(np.array(sd[:, sl.start + 1 : sl.stop]))
        body = sd[:, self._sensor_slices["trunk_contact"]][:, 0] > 0
        for leg in C.LEG_NAMES:
            body |= sd[:, self._sensor_slices[f"{leg}_thigh_contact"]][:, 0] > 0
        s["base_contact"][:] = torch.from_numpy(body.astype(np.float32))
        s["phase"][:] = self.controller.phase
        s["contact_cmd"][:] = self.controller.phase < self.buf.command["duty"]
        s["time"][:] = torch.from_numpy(self.time)
        s["diverged"][:] = torch.from_numpy(self.diverged.astype(np.float32))
