"""The CPU backend ``VecSim``: N AlienGo robots with the low-level controller, on all cores.

Design (measured in ``docs/benchmarks.md``): the robots are split into contiguous
shards, one per worker process. Each worker owns a ``mujoco.batch.Batch`` (one thread),
a Pinocchio model and the batched torch low-level controller, and runs the whole
decimation loop by itself; the main process only writes commands into shared memory
and reads the state back, once per high-level step. This spreads the Pinocchio calls,
which hold the GIL, over the cores as well as the physics. With ``num_workers=0`` a
single in-process shard is used (its ``Batch`` uses all threads), which is handy for
debugging and gives bit-identical results. The worker processes and their pipes are :mod:`cpu_workers`.

This is the ``cpu`` backend of the seam in ``sim/interface.py`` (``make_backend("cpu", ...)``); inputs may
live on any device (they are copied to the CPU; a mask of robots becomes row ids here), the state lives on the CPU.

Usage::

    sim = VecSim(mujoco.MjModel.from_xml_path(str(constants.SCENE_PATH)), num_envs=64)
    sim.set_references(freq, duty, p_td_w, F_w)   # world-frame latent references
    state = sim.step(4)                            # 4 physics steps at 200 Hz
    sim.close()
"""

from __future__ import annotations

import os
from typing import Any, Self

import mujoco
import numpy as np
import torch

from dls_quadruped.core.state import RobotState
from dls_quadruped.sim.buffers import STATE_SPECS, SharedBuffers
from dls_quadruped.sim.cpu_workers import (
    WorkerError,
    WorkerPool,
    execute,
    join_rows,
    shard_rows,
)
from dls_quadruped.sim.interface import (
    SimConfig,
    is_mask,
    reset_coordinates,
    robot_weight,
    standing_references,
)
from dls_quadruped.sim.shard import Shard

_BOOL_FIELDS = ("base_contact", "diverged")


class VecSim:
    """N robots simulated and controlled as one batch.

    Args:
        model: MuJoCo model with one AlienGo (free joint first, legs in ``constants.JOINT_NAMES``
            order) and the ground (plane or height field). Pickled to the workers.
        num_envs: number of robots N.
        cfg: backend configuration.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int,
                 cfg: SimConfig = SimConfig()):  # noqa: B008 -- frozen dataclass: an immutable default
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.model = model
        self.num_envs = num_envs
        self.cfg = cfg
        self.device = torch.device("cpu")
        self.physics_dt = float(model.opt.timestep)
        workers = cfg.num_workers if cfg.num_workers >= 0 else (os.cpu_count() or 1)
        workers = min(workers, num_envs)
        self.num_workers = workers
        self.buf = SharedBuffers.allocate(num_envs, shared=workers > 0)
        self._bounds = np.linspace(0, num_envs, max(workers, 1) + 1).round().astype(int)
        self._shard: Shard | None = None
        self.workers: WorkerPool | None = None
        """The worker processes (None with ``num_workers=0``: one shard in this process)."""
        self._init_commands()
        if workers == 0:
            self._shard = Shard(model, self.buf, cfg.control, nthread=cfg.nthread, regions=cfg.regions,
                                leg_dynamics=cfg.leg_dynamics)
        else:
            self.workers = WorkerPool(model, self.buf, cfg, self._bounds)
        self.state = self._make_state()

    # ------------------------------------------------------------------ plumbing
    def _init_commands(self) -> None:
        """Default references for every robot (:meth:`_standing_references`) and the home reset pose."""
        self._standing_references(slice(None))
        self.buf.command["reset_qpos"][:] = torch.from_numpy(self.model.key_qpos[0])

    def _standing_references(self, rows: slice | torch.Tensor) -> None:
        """References of ``rows``: standing (:func:`~dls_quadruped.sim.interface.standing_references`)."""
        standing_references(self.buf.command, rows, self.total_weight())

    @property
    def in_process_shard(self) -> Shard | None:
        """The one shard when it runs in this process (``num_workers=0``): its ``Batch``, low-level controller
        and leg terms, for benchmarks and diagnostics to read or time; None when the shards run in workers."""
        return self._shard

    def total_weight(self) -> float:
        """m g of the robot in this model [N]."""
        return robot_weight(self.model)

    def _make_state(self) -> RobotState:
        s = self.buf.state
        kwargs = {k: s[k] for k in STATE_SPECS if k not in _BOOL_FIELDS}
        state = RobotState(**kwargs, base_contact=s["base_contact"] > 0, diverged=s["diverged"] > 0)
        return state

    def _refresh_state(self) -> RobotState:
        # float buffers are live views; the bool views are recomputed
        self.state.base_contact = self.buf.state["base_contact"] > 0
        self.state.diverged = self.buf.state["diverged"] > 0
        return self.state

    def _dispatch(self, cmd: str, ids: torch.Tensor | None, payload: Any = None) -> None:
        """Send a command to the shards owning ``ids`` (all shards for None), with shard-local ids."""
        if self._shard is not None:
            if ids is None:
                arg = payload
            else:
                arg = ids.numpy() if payload is None else (payload[0], ids.numpy(), payload[1])
            execute(self._shard, cmd, arg)
            return
        self._open_workers().dispatch(cmd, ids, payload)

    def _open_workers(self) -> WorkerPool:
        if self.workers is None or not self.workers.conns:
            raise WorkerError("the simulator is closed (a worker failed earlier or close() was called)")
        return self.workers

    def _select(self, env_ids: Any, *values: Any) -> tuple[torch.Tensor, ...]:
        """(ids as a long CPU tensor, *values) of the robots ``env_ids`` names: a (N,) bool mask (values for all N
        robots, the masked rows kept) becomes row ids here, read back to the host, since MuJoCo's batch resets and
        pushes robots row by row (a CPU backend has no GPU pipeline to stall). A value of None stays None."""
        if not is_mask(env_ids, self.num_envs):
            return (torch.as_tensor(env_ids).to("cpu", torch.long).reshape(-1), *values)
        ids = torch.nonzero(env_ids.cpu()).flatten()
        return (ids, *(None if v is None else torch.as_tensor(v).to("cpu")[ids] for v in values))

    def _check_rows(self, name: str, value: torch.Tensor, n: int, shape: tuple[int, ...]) -> torch.Tensor:
        """``value`` as a float64 CPU tensor of shape (n, *shape) with finite entries (from any device)."""
        if isinstance(value, torch.Tensor):
            value = value.to("cpu", torch.float64)
        else:
            value = torch.as_tensor(value, dtype=torch.float64)
        if value.shape != (n, *shape):
            raise ValueError(f"{name} must have shape {(n, *shape)}, got {tuple(value.shape)}")
        if not torch.isfinite(value).all():
            rows = torch.nonzero(~torch.isfinite(value).reshape(n, -1).all(dim=1)).flatten().tolist()
            raise ValueError(f"{name} has non-finite values in rows {rows[:10]}")
        return value

    # ------------------------------------------------------------------ public API
    def set_references(self, freq: torch.Tensor, duty: torch.Tensor, p_td_w: torch.Tensor, F_w: torch.Tensor) -> None:
        """Latent references in the world frame for all robots, held until the next call.

        Args:
            freq: (N, 4) [Hz]; duty: (N, 4); p_td_w: (N, 4, 3) [m] foot-centre touch-down
            targets; F_w: (N, 4, 3) [N] ground-reaction forces on stance feet.
        """
        n = self.num_envs
        c = self.buf.command
        c["freq"][:] = self._check_rows("freq", freq, n, (4,))
        c["duty"][:] = self._check_rows("duty", duty, n, (4,))
        c["p_td_w"][:] = self._check_rows("p_td_w", p_td_w, n, (4, 3))
        c["F_w"][:] = self._check_rows("F_w", F_w, n, (4, 3))

    def step(self, num_physics_steps: int = 1) -> RobotState:
        """Advance every valid robot by ``num_physics_steps`` physics steps (control at each)."""
        if num_physics_steps < 1:
            raise ValueError(f"num_physics_steps must be >= 1, got {num_physics_steps}")
        self._dispatch("step", None, int(num_physics_steps))
        return self._refresh_state()

    def reset(
        self,
        env_ids: torch.Tensor,
        base_pos_w: torch.Tensor,
        base_quat_w: torch.Tensor,
        joint_pos: torch.Tensor,
        joint_vel: torch.Tensor | None = None,
        base_lin_vel_w: torch.Tensor | None = None,
        base_ang_vel_b: torch.Tensor | None = None,
        phase: torch.Tensor | None = None,
    ) -> RobotState:
        """Reset robots ``env_ids`` (ids or a mask) to the given state (velocities default to zero, phases to trot)."""
        ids, base_pos_w, base_quat_w, joint_pos, joint_vel, base_lin_vel_w, base_ang_vel_b, phase = self._select(
            env_ids, base_pos_w, base_quat_w, joint_pos, joint_vel, base_lin_vel_w, base_ang_vel_b, phase)
        n = len(ids)
        if n == 0:
            return self.state
        if ids.min() < 0 or ids.max() >= self.num_envs:
            raise ValueError(f"env_ids must be in [0, {self.num_envs}), got min {ids.min()} max {ids.max()}")
        qpos, qvel = reset_coordinates(self._check_rows, n, base_pos_w, base_quat_w, joint_pos, joint_vel,
                                       base_lin_vel_w, base_ang_vel_b)
        if phase is None:
            phase = torch.tensor([0.0, 0.5, 0.5, 0.0], dtype=torch.float64).expand(n, 4)
        c = self.buf.command
        c["reset_qpos"][ids] = qpos
        c["reset_qvel"][ids] = qvel
        c["reset_phase"][ids] = self._check_rows("phase", phase, n, (4,))
        c["wrench_w"][ids] = 0.0
        self._standing_references(ids)
        self._dispatch("reset", ids)
        return self._refresh_state()

    def set_external_wrench(self, env_ids: torch.Tensor, force_w: torch.Tensor, torque_w: torch.Tensor) -> None:
        """Constant external force [N] and torque [N m] on the base (world frame) until changed."""
        ids, force_w, torque_w = self._select(env_ids, force_w, torque_w)
        n = len(ids)
        self.buf.command["wrench_w"][ids] = torch.cat(
            [self._check_rows("force_w", force_w, n, (3,)), self._check_rows("torque_w", torque_w, n, (3,))], dim=1)

    def set_base_velocity(self, env_ids: torch.Tensor, lin_vel_w: torch.Tensor) -> RobotState:
        """Set the base linear velocity (world frame) of robots ``env_ids``: a push."""
        ids, lin_vel_w = self._select(env_ids, lin_vel_w)
        self.buf.command["set_lin_vel_w"][ids] = self._check_rows("lin_vel_w", lin_vel_w, len(ids), (3,))
        self._dispatch("set_lin_vel", ids)
        return self._refresh_state()

    def set_model_field(self, name: str, env_ids: torch.Tensor, values: torch.Tensor | np.ndarray,
                        index: np.ndarray | list[int] | None = None) -> None:
        """Per-robot model values, e.g. ``geom_friction`` (n, ngeom, 3) or ``body_mass`` (n, nbody).

        With ``index``, only those rows of the field's first dimension are written and ``values``
        is ``(n, len(index), ...)``: e.g. the four foot geoms of a terrain with thousands of geoms,
        without shipping every geom's row to the workers. Written through
        ``mujoco.batch.Batch.expand``; the controller's Pinocchio model stays nominal
        (randomisation is unmodelled dynamics for the controller).
        """
        from mujoco.batch import MODEL_FIELDS

        if name not in MODEL_FIELDS:
            raise ValueError(f"unknown model field {name!r}; allowed: mujoco.batch.MODEL_FIELDS")
        ids, values = self._select(env_ids, values.detach() if isinstance(values, torch.Tensor) else values)
        if isinstance(values, torch.Tensor):
            values = values.detach().to("cpu", torch.float64).numpy()
        values = np.asarray(values, dtype=np.float64)
        if len(values) != len(ids):
            raise ValueError(f"values must have one row per env id ({len(ids)}), got {len(values)}")
        if isinstance(index, torch.Tensor):
            index = index.cpu().numpy()
        key = name if index is None else (name, np.asarray(index, dtype=np.int64))
        self._dispatch("model_field", ids, (key, values))

    def snapshot(self) -> dict:
        """The whole simulation state of every robot, for a checkpoint: every shard's
        (``Shard.snapshot``, joined in robot order, so it does not depend on the worker count) and the
        shared state and command buffers (the last published state, the held references, wrenches)."""
        parts = self._each("snapshot", [None] * self._num_shards())
        return {"shards": join_rows(parts),
                "state": {k: v.clone() for k, v in self.buf.state.items()},
                "command": {k: v.clone() for k, v in self.buf.command.items()}}

    def restore(self, snap: dict) -> RobotState:
        """Load :meth:`snapshot` output of a simulator of as many robots (any worker count): the next
        ``step`` is bit-identical to the one the snapshot's simulator would have taken.

        Raises:
            ValueError: a snapshot of another number of robots.
        """
        n = int(snap["state"]["time"].shape[0])
        if n != self.num_envs:
            raise ValueError(f"simulator snapshot of {n} robots, this simulator has {self.num_envs}")
        b = self._bounds
        self._each("restore", [shard_rows(snap["shards"], b[w], b[w + 1]) for w in range(self._num_shards())])
        for group, saved in (("state", snap["state"]), ("command", snap["command"])):
            for k, v in getattr(self.buf, group).items():
                v.copy_(saved[k])
        return self._refresh_state()

    def _num_shards(self) -> int:
        return 1 if self._shard is not None or self.workers is None else len(self.workers.conns)

    def _each(self, cmd: str, args: list[Any]) -> list[Any]:
        """Send ``(cmd, args[w])`` to shard w, every shard; their answers in shard order."""
        if self._shard is not None:
            return [execute(self._shard, cmd, args[0])]
        return self._open_workers().each(cmd, args)

    def close(self) -> None:
        """Stop the worker processes (idempotent; a dead or hung worker is killed, not waited for)."""
        if self.workers is not None:
            self.workers.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001, S110 -- best-effort cleanup in a finalizer, which must not raise
            pass
