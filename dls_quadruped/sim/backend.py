"""Vectorised MuJoCo backend: N AlienGo robots with the low-level controller, on all cores.

Design (measured in ``docs/benchmarks.md``): the robots are split into contiguous
shards, one per worker process. Each worker owns a ``mujoco.batch.Batch`` (one thread),
a Pinocchio model and the batched torch low-level controller, and runs the whole
decimation loop by itself; the main process only writes commands into shared memory
and reads the state back, once per high-level step. This spreads the Pinocchio calls,
which hold the GIL, over the cores as well as the physics. With ``num_workers=0`` a
single in-process shard is used (its ``Batch`` uses all threads), which is handy for
debugging and gives bit-identical results.

This is the ``cpu`` backend of the seam in ``sim/interface.py`` (``make_backend("cpu", ...)``); inputs may
live on any device (they are copied to the CPU), the state lives on the CPU.

Usage::

    sim = VecSim(mujoco.MjModel.from_xml_path(str(constants.SCENE_PATH)), num_envs=64)
    sim.set_references(freq, duty, p_td_w, F_w)   # world-frame latent references
    state = sim.step(4)                            # 4 physics steps at 200 Hz
    sim.close()
"""

from __future__ import annotations

import ast
import atexit
import multiprocessing as mp
import multiprocessing.util  # registers its exit handler before ours below, so ours runs first
import os
import signal
import sys
import time
import weakref
from typing import Any

import mujoco
import numpy as np
import torch

from dls_quadruped.core.state import RobotState
from dls_quadruped.sim.interface import SimConfig, robot_weight, standing_references
from dls_quadruped.sim.shard import STATE_SPECS, Shard, SharedBuffers

_BOOL_FIELDS = ("base_contact", "diverged")


def _execute(shard: Shard, cmd: str, arg: Any) -> Any:
    """Run one backend command on a shard (same code in-process and in a worker); returns its answer
    (the snapshot for "snapshot", else None).

    ``arg`` is the step count for "step", the shard-local ids for "reset"/"set_lin_vel",
    ``(name, ids, values)`` for "model_field" and the shard's snapshot for "restore".
    """
    if cmd == "snapshot":
        return shard.snapshot()
    if cmd == "restore":
        return shard.restore(arg)
    if cmd == "step":
        shard.step(arg)
    elif cmd == "reset":
        shard.reset(arg)
    elif cmd == "set_lin_vel":
        shard.set_lin_vel(arg)
    elif cmd == "model_field":
        shard.set_model_field(*arg)
    else:
        raise ValueError(f"unknown backend command {cmd!r}")


def _join_rows(parts: list[Any]) -> Any:
    """Shard snapshots (nested dicts of arrays/tensors, rows = robots) joined along the rows."""
    if isinstance(parts[0], dict):
        return {k: _join_rows([p[k] for p in parts]) for k in parts[0]}
    if isinstance(parts[0], torch.Tensor):
        return torch.cat(parts)
    return np.concatenate(parts)


def _rows(snap: Any, lo: int, hi: int) -> Any:
    """Rows [lo, hi) of every array in a (nested dict) snapshot."""
    if isinstance(snap, dict):
        return {k: _rows(v, lo, hi) for k, v in snap.items()}
    return snap[lo:hi].clone() if isinstance(snap, torch.Tensor) else np.array(snap[lo:hi], copy=True)


class WorkerError(RuntimeError):
    """A simulator worker process died, hung or could not start."""


_RUNNING: weakref.WeakSet[VecSim] = weakref.WeakSet()
"""Simulators whose workers are running (added when they start, removed by ``close``)."""


def _close_running() -> None:
    """At interpreter exit, close every simulator the script did not close.

    Without it a script that ends by an exception, ``sys.exit`` or Ctrl-C while a ``VecSim`` is
    still referenced (a traceback holds its frame) hangs for ever: ``multiprocessing``'s own exit
    handler sends SIGTERM to daemonic children, which the workers ignore (so the trainer can save
    on Ctrl-C), then joins them without a timeout, while they wait for a command. ``atexit`` runs
    handlers last-registered-first, and this module imports ``multiprocessing.util`` before
    registering, so this runs before that join.
    """
    for sim in list(_RUNNING):
        try:
            sim.close()
        except Exception:  # noqa: BLE001, S110 -- at exit, a failure to close one must not leave the others running
            pass


atexit.register(_close_running)


def _reply(conn: Any, message: tuple) -> bool:
    """Send ``message`` to the parent; False when it is gone or stopped listening (the worker then ends
    quietly: e.g. close() after another worker died hangs up before this worker's last answer arrives)."""
    try:
        conn.send(message)
    except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
        return False
    return True


def _worker_main(conn: Any, model: mujoco.MjModel, buffers: SharedBuffers, cfg: SimConfig) -> None:
    """Worker process loop: execute commands on one shard until 'close' (or until the parent is gone)."""
    # Ctrl-C in a terminal and a SIGTERM to the process group reach the workers too; the trainer
    # handles them (it saves a checkpoint first), and a worker ends when its pipe closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    torch.set_num_threads(1)
    try:
        shard = Shard(model, buffers, cfg.control, nthread=1, regions=cfg.regions,
                      leg_dynamics=cfg.leg_dynamics)
    except Exception as err:  # report construction errors to the parent instead of hanging it
        _reply(conn, ("error", repr(err)))
        return
    if not _reply(conn, ("ok", None)):
        return
    while True:
        try:
            cmd, arg = conn.recv()
        except (EOFError, OSError):  # the parent died or closed the pipe: nothing left to serve
            return
        if cmd == "close":
            _reply(conn, ("ok", None))
            return
        try:
            answer = ("ok", _execute(shard, cmd, arg))
        except Exception as err:
            answer = ("error", f"{cmd}: {err!r}")
        if not _reply(conn, answer):
            return


def _process_state(pid: int) -> str:
    """Linux process state letter and meaning from /proc (e.g. 'T (stopped)'), or 'unknown'."""
    names = {"R": "running", "S": "sleeping", "D": "disk wait", "T": "stopped", "t": "traced", "Z": "zombie"}
    try:
        with open(f"/proc/{pid}/stat") as fh:
            letter = fh.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "unknown"
    return f"{letter} ({names.get(letter, '?')})"


def check_main_guard() -> None:
    """Refuse to start worker processes from a script's unguarded module-level code.

    Workers are started with ``spawn``: each one re-imports the main script, so a script that
    builds the simulator at module level outside ``if __name__ == "__main__":`` would start
    workers from the workers (Python refuses, the workers die). Detected before any worker starts
    from the calling frames: a module-level frame of ``__main__`` whose line is not inside such a
    guard in the script's source. A script the workers cannot re-import at all (``python - <<EOF`` reads it
    from standard input, ``__file__`` is ``<stdin>``) is refused whatever its guard: its workers would die
    while the parent blocks writing their start data.

    Raises:
        WorkerError: naming the script and line, with the fix.
    """
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or getattr(main, "__spec__", None) is not None:  # interactive, -c, -m: nothing re-imported
        return
    if not os.path.isfile(os.path.join(mp.process.ORIGINAL_DIR or "", path)):  # where spawn looks for it
        raise WorkerError(
            f"{path} starts simulator worker processes from a script that is not a file; the workers re-import "
            "the script (spawn) and cannot. Save it to a file with that code under an `if __name__ == \"__main__\":` "
            "guard (see docs/env.md) or use num_workers=0 (scene.num_workers: 0)")
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") == "__main__":
            line = frame.f_lineno
            if not _inside_main_guard(path, line):
                raise WorkerError(
                    f"{path}:{line} starts simulator worker processes from module-level code without an "
                    "`if __name__ == \"__main__\":` guard; the workers re-import the script (spawn) and would "
                    "start workers themselves. Put that code under the guard (see docs/env.md) or use "
                    "num_workers=0 (scene.num_workers: 0)")
            return
        frame = frame.f_back


def _inside_main_guard(path: str, line: int) -> bool:
    """Whether ``line`` of the script lies in the body of a top-level ``if __name__ == "__main__":``."""
    try:
        with open(path) as fh:
            tree = ast.parse(fh.read())
    except (OSError, SyntaxError):
        return True  # cannot tell: do not block
    for node in tree.body:
        if (isinstance(node, ast.If) and _is_main_test(node.test)
                and any(n.lineno <= line <= (n.end_lineno or n.lineno) for n in node.body)):
            return True
    return False


def _is_main_test(test: ast.expr) -> bool:
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    names = [s.id for s in sides if isinstance(s, ast.Name)]
    consts = [s.value for s in sides if isinstance(s, ast.Constant)]
    return names == ["__name__"] and consts == ["__main__"]


class VecSim:
    """N robots simulated and controlled as one batch.

    Args:
        model: MuJoCo model with one AlienGo (free joint first, legs in ``constants.JOINT_NAMES``
            order) and the ground (plane or height field). Pickled to the workers.
        num_envs: number of robots N.
        cfg: backend configuration.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, cfg: SimConfig = SimConfig()):
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
        self._conns: list[Any] = []
        self._procs: list[mp.Process] = []
        self._shard: Shard | None = None
        self._init_commands()
        if workers == 0:
            self._shard = Shard(model, self.buf, cfg.control, nthread=cfg.nthread, regions=cfg.regions,
                                leg_dynamics=cfg.leg_dynamics)
        else:
            check_main_guard()
            ctx = mp.get_context("spawn")
            _RUNNING.add(self)  # before the first start: a Ctrl-C between two starts still closes the first
            for w in range(workers):
                parent, child = ctx.Pipe()
                rows = self.buf.rows(self._bounds[w], self._bounds[w + 1])
                proc = ctx.Process(target=_worker_main, args=(child, model, rows, cfg), daemon=True)
                proc.start()
                child.close()  # only the worker holds its end: a dead worker then reads as EOF, not a hang
                self._conns.append(parent)
                self._procs.append(proc)
            self._gather("start")
        self.state = self._make_state()

    # ------------------------------------------------------------------ plumbing
    def _init_commands(self) -> None:
        """Default references for every robot (:meth:`_standing_references`) and the home reset pose."""
        self._standing_references(slice(None))
        self.buf.command["reset_qpos"][:] = torch.from_numpy(self.model.key_qpos[0])

    def _standing_references(self, rows: slice | torch.Tensor) -> None:
        """References of ``rows``: standing (:func:`~dls_quadruped.sim.interface.standing_references`)."""
        standing_references(self.buf.command, rows, self.total_weight())

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

    def _died(self, w: int, during: str) -> WorkerError:
        """The error for a worker that is gone (waits briefly for its exit code)."""
        proc = self._procs[w]
        proc.join(timeout=1.0)
        msg = f"simulator worker {w} (pid {proc.pid}) died with exit code {proc.exitcode} during {during}"
        if proc.exitcode is not None and proc.exitcode < 0:
            msg += f" (killed by {signal.Signals(-proc.exitcode).name})"
        if during == "start":
            msg += ("; if the script builds the env or VecSim at module level, put that code under "
                    "`if __name__ == \"__main__\":` (workers are spawned and re-import the script), "
                    "or use num_workers=0")
        return WorkerError(msg)

    def _send(self, w: int, message: tuple, during: str) -> None:
        try:
            self._conns[w].send(message)
        except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
            raise self._died(w, during) from None

    def _recv(self, w: int, during: str) -> tuple[str, Any]:
        """Worker ``w``'s answer; a dead worker or no answer within the timeout raises ``WorkerError``."""
        conn, proc = self._conns[w], self._procs[w]
        timeout = self.cfg.start_timeout_s if during == "start" else self.cfg.reply_timeout_s
        deadline = time.monotonic() + timeout
        while not conn.poll(0.5):
            if not proc.is_alive():
                raise self._died(w, during)
            if time.monotonic() > deadline:
                raise WorkerError(f"simulator worker {w} (pid {proc.pid}) gave no answer within {timeout:g} s "
                                  f"during {during} (process state: {_process_state(proc.pid)}); "
                                  "SimConfig.reply_timeout_s sets the limit")
        try:
            return conn.recv()
        except (EOFError, ConnectionResetError, OSError):
            raise self._died(w, during) from None

    def _gather(self, what: str) -> None:
        errors = []
        for w in range(len(self._conns)):
            status, msg = self._recv(w, what)
            if status != "ok":
                errors.append(f"worker {w}: {msg}")
        if errors:
            raise RuntimeError(f"simulator backend failed during {what}: " + "; ".join(errors))

    def _dispatch(self, cmd: str, ids: torch.Tensor | None, payload: Any = None) -> None:
        """Send a command to the shards owning ``ids`` (all shards for None), with shard-local ids."""
        if self._shard is not None:
            if ids is None:
                arg = payload
            else:
                arg = ids.numpy() if payload is None else (payload[0], ids.numpy(), payload[1])
            _execute(self._shard, cmd, arg)
            return
        if not self._conns:
            raise WorkerError("the simulator is closed (a worker failed earlier or close() was called)")
        busy = []
        for w in range(len(self._conns)):
            lo, hi = self._bounds[w], self._bounds[w + 1]
            if ids is None:
                arg = payload
            else:
                mask = (ids >= lo) & (ids < hi)
                if not mask.any():
                    continue
                local = (ids[mask] - lo).numpy()
                arg = local if payload is None else (payload[0], local, payload[1][mask.numpy()])
            self._send(w, (cmd, arg), cmd)
            busy.append(w)
        errors = [msg for w in busy for status, msg in [self._recv(w, cmd)] if status != "ok"]
        if errors:
            raise RuntimeError("simulator backend failed: " + "; ".join(errors))

    @staticmethod
    def _ids(env_ids: torch.Tensor | np.ndarray | list[int]) -> torch.Tensor:
        if isinstance(env_ids, torch.Tensor):
            return env_ids.to("cpu", torch.long).reshape(-1)
        return torch.as_tensor(env_ids, dtype=torch.long).reshape(-1)

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
        """Reset robots ``env_ids`` to the given state (velocities default to zero, phases to trot)."""
        ids = self._ids(env_ids)
        n = len(ids)
        if n == 0:
            return self.state
        if ids.min() < 0 or ids.max() >= self.num_envs:
            raise ValueError(f"env_ids must be in [0, {self.num_envs}), got min {ids.min()} max {ids.max()}")
        zeros3 = torch.zeros(n, 3, dtype=torch.float64)
        quat = self._check_rows("base_quat_w", base_quat_w, n, (4,))
        qpos = torch.cat(
            [self._check_rows("base_pos_w", base_pos_w, n, (3,)), quat / quat.norm(dim=1, keepdim=True),
             self._check_rows("joint_pos", joint_pos, n, (12,))], dim=1)
        qvel = torch.cat(
            [zeros3 if base_lin_vel_w is None else self._check_rows("base_lin_vel_w", base_lin_vel_w, n, (3,)),
             zeros3 if base_ang_vel_b is None else self._check_rows("base_ang_vel_b", base_ang_vel_b, n, (3,)),
             torch.zeros(n, 12, dtype=torch.float64) if joint_vel is None
             else self._check_rows("joint_vel", joint_vel, n, (12,))], dim=1)
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
        ids = self._ids(env_ids)
        n = len(ids)
        self.buf.command["wrench_w"][ids] = torch.cat(
            [self._check_rows("force_w", force_w, n, (3,)), self._check_rows("torque_w", torque_w, n, (3,))], dim=1)

    def set_base_velocity(self, env_ids: torch.Tensor, lin_vel_w: torch.Tensor) -> RobotState:
        """Set the base linear velocity (world frame) of robots ``env_ids``: a push."""
        ids = self._ids(env_ids)
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
        ids = self._ids(env_ids)
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
        return {"shards": _join_rows(parts),
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
        self._each("restore", [_rows(snap["shards"], b[w], b[w + 1]) for w in range(self._num_shards())])
        for group, saved in (("state", snap["state"]), ("command", snap["command"])):
            for k, v in getattr(self.buf, group).items():
                v.copy_(saved[k])
        return self._refresh_state()

    def _num_shards(self) -> int:
        return 1 if self._shard is not None else len(self._conns)

    def _each(self, cmd: str, args: list[Any]) -> list[Any]:
        """Send ``(cmd, args[w])`` to shard w, every shard; their answers in shard order."""
        if self._shard is not None:
            return [_execute(self._shard, cmd, args[0])]
        if not self._conns:
            raise WorkerError("the simulator is closed (a worker failed earlier or close() was called)")
        for w, arg in enumerate(args):
            self._send(w, (cmd, arg), cmd)
        answers = [self._recv(w, cmd) for w in range(len(args))]
        errors = [msg for status, msg in answers if status != "ok"]
        if errors:
            raise RuntimeError("simulator backend failed: " + "; ".join(errors))
        return [msg for _, msg in answers]

    def close(self) -> None:
        """Stop the worker processes (idempotent; a dead or hung worker is killed, not waited for)."""
        deadline = time.monotonic() + 5.0  # for all workers together
        for conn in self._conns:
            try:
                conn.send(("close", None))
            except (BrokenPipeError, EOFError, OSError):
                pass
        for conn, proc in zip(self._conns, self._procs):
            try:
                stopped = _process_state(proc.pid).startswith(("T", "t"))  # cannot answer: kill it below
                if not stopped and conn.poll(max(0.0, deadline - time.monotonic())):
                    conn.recv()
            except (BrokenPipeError, EOFError, OSError):
                pass
            conn.close()
        for proc in self._procs:
            if not _process_state(proc.pid).startswith(("T", "t")):
                proc.join(timeout=max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()  # SIGTERM is ignored by workers; a stopped one ignores everything but SIGKILL
                proc.join(timeout=5)
        self._conns, self._procs = [], []
        _RUNNING.discard(self)

    def __enter__(self) -> VecSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

