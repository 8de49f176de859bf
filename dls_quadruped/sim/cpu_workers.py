"""The worker processes of the CPU backend (:class:`~dls_quadruped.sim.cpu_backend.VecSim`).

Each worker owns one :class:`~dls_quadruped.sim.shard.Shard` (a one-thread ``mujoco.batch.Batch``, a
Pinocchio model and the batched low-level controller) and serves the main process's commands over a pipe:
``step`` (k physics steps), ``reset``, ``set_lin_vel``, ``model_field``, ``snapshot``, ``restore`` and
``close``; state and commands travel through shared memory (:class:`~dls_quadruped.sim.buffers.SharedBuffers`).
The main process's end is :class:`WorkerPool` (start, commands to the shards owning some robots, answers with
timeouts, close). Here also: a snapshot cut into shards' rows and joined again, the check that refuses to spawn
workers from a script's unguarded module-level code, the process-state probe behind the hang diagnostics, and the
exit handler that closes the worker pools a script left open.
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

from dls_quadruped.sim.buffers import SharedBuffers
from dls_quadruped.sim.interface import SimConfig
from dls_quadruped.sim.shard import Shard


def execute(shard: Shard, cmd: str, arg: Any) -> Any:
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


def join_rows(parts: list[Any]) -> Any:
    """Shard snapshots (nested dicts of arrays/tensors, rows = robots) joined along the rows."""
    if isinstance(parts[0], dict):
        return {k: join_rows([p[k] for p in parts]) for k in parts[0]}
    if isinstance(parts[0], torch.Tensor):
        return torch.cat(parts)
    return np.concatenate(parts)


def shard_rows(snap: Any, lo: int, hi: int) -> Any:
    """Rows [lo, hi) of every array in a (nested dict) snapshot."""
    if isinstance(snap, dict):
        return {k: shard_rows(v, lo, hi) for k, v in snap.items()}
    return snap[lo:hi].clone() if isinstance(snap, torch.Tensor) else np.array(snap[lo:hi], copy=True)


class WorkerError(RuntimeError):
    """A simulator worker process died, hung or could not start."""


RUNNING: weakref.WeakSet[WorkerPool] = weakref.WeakSet()
"""Worker pools whose processes are running (added when they start, removed by ``close``)."""


def _close_running() -> None:
    """At interpreter exit, close every simulator the script did not close.

    Without it a script that ends by an exception, ``sys.exit`` or Ctrl-C while a ``VecSim`` is
    still referenced (a traceback holds its frame) hangs for ever: ``multiprocessing``'s own exit
    handler sends SIGTERM to daemonic children, which the workers ignore (so the trainer can save
    on Ctrl-C), then joins them without a timeout, while they wait for a command. ``atexit`` runs
    handlers last-registered-first, and this module imports ``multiprocessing.util`` before
    registering, so this runs before that join.
    """
    for pool in list(RUNNING):
        try:
            pool.close()
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


def worker_main(conn: Any, model: mujoco.MjModel, buffers: SharedBuffers, cfg: SimConfig) -> None:
    """Worker process loop: execute commands on one shard until 'close' (or until the parent is gone)."""
    # Ctrl-C in a terminal and a SIGTERM to the process group reach the workers too; the trainer
    # handles them (it saves a checkpoint first), and a worker ends when its pipe closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    torch.set_num_threads(1)
    try:
        shard = Shard(model, buffers, cfg.control, nthread=1, regions=cfg.regions,
                      leg_dynamics=cfg.leg_dynamics)
    except Exception as err:  # noqa: BLE001 -- report construction errors to the parent instead of hanging it
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
            answer = ("ok", execute(shard, cmd, arg))
        except Exception as err:  # noqa: BLE001 -- any failure of a command goes back to the parent as its answer
            answer = ("error", f"{cmd}: {err!r}")
        if not _reply(conn, answer):
            return


class WorkerPool:
    """The main process's end of a ``VecSim``'s worker processes: worker w serves robots ``bounds[w]:bounds[w + 1]``
    (:func:`worker_main`), started here and waited for.

    Args:
        model: the MuJoCo model (pickled to each worker).
        buffers: all robots' shared buffers (each worker gets its rows).
        cfg: the backend's configuration (timeouts, the shards' settings).
        bounds: (W + 1,) row bounds of the W workers.

    Attributes:
        conns, procs: each worker's pipe and process (empty once closed).

    Raises:
        WorkerError: a worker died or gave no answer while starting (the others are closed).
    """

    def __init__(self, model: mujoco.MjModel, buffers: SharedBuffers, cfg: SimConfig, bounds: np.ndarray) -> None:
        check_main_guard()
        self.cfg, self.bounds = cfg, bounds
        self.conns: list[Any] = []
        self.procs: list[mp.Process] = []
        ctx = mp.get_context("spawn")
        RUNNING.add(self)  # before the first start: a Ctrl-C between two starts still closes the first
        try:
            for w in range(len(bounds) - 1):
                parent, child = ctx.Pipe()
                rows = buffers.rows(bounds[w], bounds[w + 1])
                proc = ctx.Process(target=worker_main, args=(child, model, rows, cfg), daemon=True)
                proc.start()
                child.close()  # only the worker holds its end: a dead worker then reads as EOF, not a hang
                self.conns.append(parent)
                self.procs.append(proc)
            self.gather("start")
        except BaseException:
            self.close()
            raise

    def died(self, w: int, during: str) -> WorkerError:
        """The error for a worker that is gone (waits briefly for its exit code)."""
        proc = self.procs[w]
        proc.join(timeout=1.0)
        msg = f"simulator worker {w} (pid {proc.pid}) died with exit code {proc.exitcode} during {during}"
        if proc.exitcode is not None and proc.exitcode < 0:
            msg += f" (killed by {signal.Signals(-proc.exitcode).name})"
        if during == "start":
            msg += ("; if the script builds the env or VecSim at module level, put that code under "
                    "`if __name__ == \"__main__\":` (workers are spawned and re-import the script), "
                    "or use num_workers=0")
        return WorkerError(msg)

    def send(self, w: int, message: tuple, during: str) -> None:
        """``message`` to worker ``w``; a dead worker raises ``WorkerError``."""
        try:
            self.conns[w].send(message)
        except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
            raise self.died(w, during) from None

    def recv(self, w: int, during: str) -> tuple[str, Any]:
        """Worker ``w``'s answer; a dead worker or no answer within the timeout raises ``WorkerError``."""
        conn, proc = self.conns[w], self.procs[w]
        timeout = self.cfg.start_timeout_s if during == "start" else self.cfg.reply_timeout_s
        deadline = time.monotonic() + timeout
        while not conn.poll(0.5):
            if not proc.is_alive():
                raise self.died(w, during)
            if time.monotonic() > deadline:
                raise WorkerError(f"simulator worker {w} (pid {proc.pid}) gave no answer within {timeout:g} s "
                                  f"during {during} (process state: {process_state(proc.pid)}); "
                                  "SimConfig.reply_timeout_s sets the limit")
        try:
            return conn.recv()
        except (EOFError, ConnectionResetError, OSError):
            raise self.died(w, during) from None

    def gather(self, what: str) -> None:
        """Every worker's answer to ``what``; a RuntimeError naming the workers that answered with an error."""
        errors = []
        for w in range(len(self.conns)):
            status, msg = self.recv(w, what)
            if status != "ok":
                errors.append(f"worker {w}: {msg}")
        if errors:
            raise RuntimeError(f"simulator backend failed during {what}: " + "; ".join(errors))

    def dispatch(self, cmd: str, ids: torch.Tensor | None, payload: Any = None) -> None:
        """Send a command to the workers owning ``ids`` (all for None), with worker-local ids, and wait for them.

        ``payload``: the step count (``ids`` None), or ``(key, values)`` of a model field (values row-aligned with
        ``ids``)."""
        busy = []
        for w in range(len(self.conns)):
            lo, hi = self.bounds[w], self.bounds[w + 1]
            if ids is None:
                arg = payload
            else:
                mask = (ids >= lo) & (ids < hi)
                if not mask.any():
                    continue
                local = (ids[mask] - lo).numpy()
                arg = local if payload is None else (payload[0], local, payload[1][mask.numpy()])
            self.send(w, (cmd, arg), cmd)
            busy.append(w)
        errors = [msg for w in busy for status, msg in [self.recv(w, cmd)] if status != "ok"]
        if errors:
            raise RuntimeError("simulator backend failed: " + "; ".join(errors))

    def each(self, cmd: str, args: list[Any]) -> list[Any]:
        """Send ``(cmd, args[w])`` to worker w, every worker; their answers in worker order."""
        for w, arg in enumerate(args):
            self.send(w, (cmd, arg), cmd)
        answers = [self.recv(w, cmd) for w in range(len(args))]
        errors = [msg for status, msg in answers if status != "ok"]
        if errors:
            raise RuntimeError("simulator backend failed: " + "; ".join(errors))
        return [msg for _, msg in answers]

    def close(self) -> None:
        """Stop the worker processes (idempotent; a dead or hung worker is killed, not waited for)."""
        deadline = time.monotonic() + 5.0  # for all workers together
        for conn in self.conns:
            try:
                conn.send(("close", None))
            except (BrokenPipeError, EOFError, OSError):
                pass
        for conn, proc in zip(self.conns, self.procs):
            try:
                stopped = process_state(proc.pid).startswith(("T", "t"))  # cannot answer: kill it below
                if not stopped and conn.poll(max(0.0, deadline - time.monotonic())):
                    conn.recv()
            except (BrokenPipeError, EOFError, OSError):
                pass
            conn.close()
        for proc in self.procs:
            if not process_state(proc.pid).startswith(("T", "t")):
                proc.join(timeout=max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()  # SIGTERM is ignored by workers; a stopped one ignores everything but SIGKILL
                proc.join(timeout=5)
        self.conns, self.procs = [], []
        RUNNING.discard(self)


def process_state(pid: int) -> str:
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
