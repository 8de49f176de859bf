"""One CUDA graph per env step: :meth:`LocomotionEnv.step` replayed from a graph (``scene.cuda_graph``).

An env step on the GPU is ~20 ms of host work issuing ~1 300 kernels that keep the GPU busy for ~4.5 ms
(docs/gpu.md). Captured whole -- the compiled torch pieces, the managers, the masked reset, the pushes and MuJoCo
Warp's kernels of the four physics steps -- it is one ``torch.cuda.CUDAGraph.replay()``:

* **Warm-up.** The first :data:`GRAPH_WARMUP` steps (in each grad/inference mode) run eagerly: ``torch.compile``
  compiles, Warp loads its kernels, the managers build their caches.
* **Capture.** The next step is captured on a side stream (``torch.cuda.graph``); Warp is told the capture is
  external (``wp.capture_begin(external=True)`` on the same stream, the pattern of Warp's own torch tests; both in
  thread-local capture mode, since Warp must be told the mode torch opened the capture in), so
  MuJoCo Warp's solver loop becomes a conditional node of this graph, and its phases launch their kernels into it
  instead of replaying their own graphs (``WarpSim.graph_body``). A capture runs nothing: the graph is replayed
  once right after.
* **Replay.** Later steps copy the actions into the graph's input and replay. What a graph cannot do is done
  around it, on the host: the step counters, the backend's checks every ``check_every`` calls
  (``WarpSim.count_step``), and copies of the outputs (the graph overwrites its own at the next replay;
  rsl-rl keeps the observations it acted on until the step returns).
* **Captured again** when the grad/inference mode changes, when an array the graph reads was replaced (a model
  field made per-robot for the first time: ``WarpWorlds.generation``), and after ``env.reset`` or
  ``env.load_state_dict`` (they may replace what the step reads). A capture that fails is tried once more after
  another warm-up (a late recompile inside it, say); a second failure warns once, with both reasons, and the env
  steps eagerly from then on.

**What a graph needs of the step**, and how it is checked on a CPU: a replay re-runs the kernels on the addresses
they had at capture, and no Python. So state kept from one step to the next must be written in place: an attribute
the step *replaces* (``self.x = f(self.x)``) would, on replay, be read at the tensor the capture read and written to
the one it made. :class:`EmulatedCapture` does on the CPU exactly what a replay does to the objects Python sees
(reads at the capture's first tensors, writes into the capture's outputs) while computing eagerly, and refuses a
step whose replaced attributes or Python numbers differ from the capture's: an env stepped through it must give
bit for bit what the eager env gives (``tests/envs/test_env_graph.py``, on ``warp-cpu`` with ``scene.compile``).
It is the same code path as on CUDA except for the torch graph itself.
"""

from __future__ import annotations

import warnings
from collections import deque
from collections.abc import Callable
from typing import Any

import torch

GRAPH_WARMUP = 3
"""Eager env steps (per grad/inference mode) before the capture: compiled functions compile on their first or
second call (``core/compile.py`` ``eager_first``)."""

CAPTURE_TRIES = 2
"""Captures tried (each after :data:`GRAPH_WARMUP` eager steps) before the env steps eagerly for good."""

Path = tuple[tuple[str, Any], ...]
_MISSING = object()


class GraphMismatch(RuntimeError):
    """A step that a replayed graph would not reproduce (:class:`EmulatedCapture`)."""


class CudaCapture:
    """A ``torch.cuda.CUDAGraph`` of one env step, Warp's kernels captured into it as an external capture.

    Args:
        device: the env's CUDA device.
    """

    def __init__(self, device: torch.device):
        self.device = torch.device(device)
        self.graph: torch.cuda.CUDAGraph | None = None
        self._streams: tuple = ()

    def reset(self) -> None:
        self.graph = None

    def capture(self, body: Callable[[Any], Any]) -> Any:
        """Capture ``body(warp_stream)`` and replay it once (a capture runs nothing); returns its outputs."""
        import warp as wp  # the [gpu] extra

        graph = torch.cuda.CUDAGraph()
        stream = torch.cuda.Stream(self.device)
        stream.wait_stream(torch.cuda.current_stream(self.device))
        wstream = wp.stream_from_torch(stream)  # Warp finds its capture by this object: the backend uses it
        self._streams = (stream, wstream)
        # Warp is told the mode torch opened the capture in (its contract for an external capture): thread-local
        with (wp.ScopedDevice(wp.device_from_torch(self.device)), wp.ScopedStream(wstream),
              torch.cuda.graph(graph, stream=stream, capture_error_mode="thread_local")):
            wp.capture_begin(stream=wstream, force_module_load=False, external=True,
                             capture_mode=wp.CaptureMode.THREAD_LOCAL)
            try:
                out = body(wstream)
            finally:
                wp.capture_end(stream=wstream)
        self.graph = graph
        graph.replay()
        return out

    def replay(self) -> None:
        self.graph.replay()


class EmulatedCapture:
    """What a CUDA graph's replay does to the Python-visible state, done eagerly (CPU devices, tests).

    At capture the step runs once and the objects it *replaced* are noted (top-most attributes, dict or list entries
    whose object changed, in the object tree of ``root``: the package's objects, dicts, lists, tuples and
    TensorDicts). A replay then puts back, at each of those places, the object the capture found there (a graph
    reads the addresses the capture read), runs the step, copies what it made into the capture's objects and puts
    those back (a graph writes the addresses the capture wrote).

    Raises :class:`GraphMismatch` at a replay whose step replaced other places than the capture's, or that changed a
    Python number (a graph runs no Python), or whose objects do not match the capture's in structure.

    Args:
        root: the env.
        skip: objects whose insides are not walked (e.g. the ``cpu`` backend, whose host state no graph holds, when
            the managers' state is what is checked).
    """

    def __init__(self, root: Any, skip: tuple = ()):
        self.root = root
        self.skip = frozenset(map(id, skip))
        self.body: Callable[[Any], Any] | None = None
        self.outputs: Any = None
        self.moved: dict[Path, tuple[Any, Any]] = {}
        """Place -> (the object the capture found there, the one it left)."""

    def reset(self) -> None:
        self.body = self.outputs = None
        self.moved = {}

    def capture(self, body: Callable[[Any], Any]) -> Any:
        before = object_tree(self.root, self.skip)
        out = body(None)
        after = object_tree(self.root, self.skip)
        _refuse_scalar_changes(before, after, "the captured step")
        self.moved = {p: (before.get(p, _MISSING), after[p]) for p in replaced(before, after)}
        self.body, self.outputs = body, out
        return out

    def replay(self) -> None:
        for path, (first, _) in self.moved.items():
            if first is not _MISSING:
                _set(self.root, path, first)
        before = object_tree(self.root, self.skip)
        out = self.body(None)
        after = object_tree(self.root, self.skip)
        _refuse_scalar_changes(before, after, "a replayed step")
        now = set(replaced(before, after))
        if now != set(self.moved):
            raise GraphMismatch(f"a replayed step replaced {sorted(map(path_name, now - set(self.moved)))} and not "
                                f"{sorted(map(path_name, set(self.moved) - now))}, unlike its capture: a graph "
                                "would not see it")
        for path, (_, captured) in self.moved.items():
            copy_into(captured, after[path], path_name(path))
            _set(self.root, path, captured)
        copy_into(self.outputs, out, "the step's outputs")


def _children(obj: Any) -> list[tuple[tuple[str, Any], Any]]:
    """(step, child) pairs of a container the tree walks into; [] for a leaf or an object it does not enter."""
    if isinstance(obj, dict):
        return [(("item", k), v) for k, v in obj.items()]
    if isinstance(obj, (list, tuple)):
        return [(("item", i), v) for i, v in enumerate(obj)]
    if type(obj).__name__ == "TensorDict":
        return [(("item", k), v) for k, v in obj.items()]
    module = type(obj).__module__ or ""
    if module.startswith("dls_quadruped") and module != __name__ and hasattr(obj, "__dict__"):  # not the graph
        return [(("attr", k), v) for k, v in vars(obj).items()]
    return []


def object_tree(root: Any, skip: frozenset[int] = frozenset()) -> dict[Path, Any]:
    """Every object reachable from ``root`` (breadth first, each object at its first path) by its path; Python
    numbers, strings and None as values (their identity means nothing); the objects whose ids are in ``skip`` are
    leaves."""
    out: dict[Path, Any] = {}
    seen: set[int] = set(skip)
    queue: deque[tuple[Any, Path]] = deque([(root, ())])
    while queue:
        obj, path = queue.popleft()
        if _is_value(obj):
            out[path] = obj
            continue
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        out[path] = obj
        if not isinstance(obj, torch.Tensor):
            queue.extend((child, (*path, step)) for step, child in _children(obj))
    return out


def _is_number(x: Any) -> bool:
    return isinstance(x, (bool, int, float))


def _is_value(x: Any) -> bool:
    return x is None or isinstance(x, (bool, int, float, str))


def replaced(before: dict[Path, Any], after: dict[Path, Any]) -> list[Path]:
    """The top-most places whose object changed between two :func:`object_tree` walks (their parent did not)."""
    out = []
    for path, obj in after.items():
        old = before.get(path, _MISSING)
        if not path or _is_value(obj) and _is_value(old):  # numbers: _refuse_scalar_changes
            continue
        parent = path[:-1]
        if old is not obj and before.get(parent, _MISSING) is after.get(parent):
            out.append(path)
    return out


def _refuse_scalar_changes(before: dict[Path, Any], after: dict[Path, Any], what: str) -> None:
    changed = [path_name(p) for p, v in after.items() if _is_number(v) and p in before and before[p] != v]
    if changed:
        raise GraphMismatch(f"{what} changed Python numbers {changed[:8]}: a graph runs no Python")


def path_name(path: Path) -> str:
    return "env" + "".join(f".{k}" if kind == "attr" else f"[{k!r}]" for kind, k in path)


def _get(root: Any, path: Path) -> Any:
    obj = root
    for kind, k in path:
        obj = getattr(obj, k) if kind == "attr" else obj[k]
    return obj


def _set(root: Any, path: Path, value: Any) -> None:
    parent = _get(root, path[:-1])
    kind, k = path[-1]
    if kind == "attr":
        setattr(parent, k, value)
    else:
        parent[k] = value


def copy_into(dst: Any, src: Any, where: str) -> None:
    """Copy the tensors of ``src`` into those of ``dst`` in place (same structure; Python numbers must be equal)."""
    if dst is src:
        return
    if isinstance(dst, torch.Tensor):
        if not isinstance(src, torch.Tensor) or src.shape != dst.shape or src.dtype != dst.dtype:
            raise GraphMismatch(f"{where}: a tensor {tuple(dst.shape)} {dst.dtype} at capture, now {src!r:.80}")
        dst.copy_(src)
        return
    if _is_value(dst):
        if dst != src:
            raise GraphMismatch(f"{where}: {dst!r} at capture, now {src!r}")
        return
    a, b = _children(dst), _children(src)
    if [s for s, _ in a] != [s for s, _ in b]:
        raise GraphMismatch(f"{where}: entries {[s for s, _ in a]} at capture, now {[s for s, _ in b]}")
    for (step, d), (_, s) in zip(a, b):
        copy_into(d, s, f"{where}[{step[1]!r}]")


class EnvGraph:
    """:meth:`LocomotionEnv.step` replayed from one captured graph (module doc).

    Args:
        env: the env (a Warp backend on its device).
        capture: :class:`CudaCapture` or :class:`EmulatedCapture` (default: the first on CUDA, else the second).
        warmup: eager steps per grad/inference mode before the capture.

    Attributes:
        captures: graphs captured so far.
        replays: steps replayed from a graph.
        eager_steps: steps run without one (warm-up, after a failed capture).
        failures: why each failed capture failed.
        error: set after :data:`CAPTURE_TRIES` failures (each after its own warm-up); the env then steps eagerly.
    """

    def __init__(self, env: Any, capture: CudaCapture | EmulatedCapture | None = None, warmup: int = GRAPH_WARMUP):
        self.env = env
        self.sim = env.scene.sim
        if capture is None:
            capture = CudaCapture(env.device) if env.device.type == "cuda" else EmulatedCapture(env)
        self.impl = capture
        self.warmup = warmup
        self.actions: torch.Tensor | None = None  # the graph's input
        self.outputs: tuple | None = None  # the graph's outputs: obs, reward, dones, time_outs
        self.key: tuple | None = None
        self.warm = 0
        self.captures = self.replays = self.eager_steps = 0
        self.error: str | None = None
        self.failures: list[str] = []  # the reasons of the failed captures so far

    def _key(self) -> tuple:
        return torch.is_grad_enabled(), torch.is_inference_mode_enabled(), self.env.graph_generation()

    def step(self, actions: torch.Tensor) -> tuple:
        """One env step of the (num_envs, num_actions) float32 device ``actions`` (checked on the host)."""
        if self.error is not None:
            return self._eager(actions)
        key = self._key()
        if key != self.key:
            if self.key is None or key[:2] != self.key[:2]:
                self.warm = 0  # another mode: the compiled functions compile again
            self.key, self.outputs = key, None
            self.impl.reset()
        if self.outputs is None:
            if self.warm < self.warmup:
                self.warm += 1
                return self._eager(actions)
            return self._capture(actions)
        self.actions.copy_(actions)
        self.impl.replay()
        self.replays += 1
        self.sim.count_step()
        return self._publish()

    def _eager(self, actions: torch.Tensor) -> tuple:
        self.eager_steps += 1
        return self.env.step_body(actions)

    def _body(self, stream: Any) -> tuple:
        with self.sim.graph_body(stream):
            obs, reward, dones, extras = self.env.step_body(self.actions)
        return obs, reward, dones, extras["time_outs"]

    def _capture(self, actions: torch.Tensor) -> tuple:
        self.actions = actions.clone()
        try:
            self.outputs = self.impl.capture(self._body)
        except Exception as err:  # noqa: BLE001 - a capture that fails must not stop a run
            self.outputs = None
            self.impl.reset()
            self.failures.append(f"{type(err).__name__}: {err}")
            if len(self.failures) < CAPTURE_TRIES:  # e.g. a late recompile inside the capture: warm up, try again
                self.warm = 0
            else:
                self.error = "; then ".join(self.failures)
                warnings.warn(f"capturing the env step as one CUDA graph failed {len(self.failures)} times "
                              f"({self.error}); the env steps without it from now on (scene.cuda_graph, "
                              "docs/gpu.md)", RuntimeWarning, stacklevel=3)
            return self._eager(actions)  # the capture ran nothing: this step runs now
        self.captures += 1
        self.sim.count_step()
        return self._publish()

    def _publish(self) -> tuple:
        """Copies of the graph's outputs (the next replay overwrites them), set as the env's ``obs_buf`` and
        ``extras`` as an eager step does."""
        obs, reward, dones, time_outs = self.outputs
        env = self.env
        env.obs_buf = obs.clone()
        env.extras = {"time_outs": time_outs.clone(), "log": {}}
        return env.obs_buf, reward.clone(), dones.clone(), env.extras


def make(env: Any) -> EnvGraph | None:
    """``scene.cuda_graph`` of ``env``: its step's graph, or None; refused where it cannot run.

    Raises:
        ConfigError: a backend without :meth:`WarpSim.graph_body` (the ``cpu`` one), or the env on another device.
    """
    if not env.scene.cfg.cuda_graph:
        return None
    sim = env.scene.sim
    if not hasattr(sim, "graph_body"):
        raise env.task.error("scene.cuda_graph", "needs a Warp backend (cuda; warp-cpu emulates the graph), "
                                                 f"not {env.scene.cfg.backend!r}")
    if sim.device.type != env.device.type:
        raise env.task.error("scene.cuda_graph", f"needs the env on the simulator's device ({sim.device}), "
                                                 f"got device={env.device}")
    return EnvGraph(env)
