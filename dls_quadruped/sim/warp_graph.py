"""MuJoCo Warp's step phases replayed from captured Warp graphs instead of launched kernel by kernel.

:class:`StepGraph` wraps one MuJoCo Warp call (``step1`` or ``step2`` of the two-phase step) on one model and
data. Its first call runs the phase directly (Warp compiles and loads the kernels: loading is not allowed
while capturing); the second captures it with ``wp.ScopedCapture`` on a stream of its own and replays the
graph; later calls replay. On CUDA a graph launch replaces the phase's few hundred kernel launches, and the
solver's convergence loop becomes a conditional graph node (MuJoCo Warp's ``opt.graph_conditional``), so
no iteration count is copied to the host. Warp 1.19 records and replays graphs on its CPU device too, so the
same path runs (and is tested) on ``warp-cpu``.

A graph holds the addresses of the arrays it was captured with. Writing *into* an array (a state, a
per-robot friction) needs nothing; replacing an array object (a model field made per-robot for the first
time, ``WarpSim._batched_field``) does: :meth:`StepGraph.invalidate` then makes the next call capture again.

Ordering on CUDA without a host wait: the graph runs on its own stream (CUDA cannot capture the legacy
default stream, which is torch's default), which first waits for torch's current stream (an event) and is
then waited for by it.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import warp as wp


class StepGraph:
    """One MuJoCo Warp phase ``fn(m, d)``, captured on its second call and replayed after.

    Args:
        fn: the phase, e.g. ``mujoco_warp.step2``.
        m: MuJoCo Warp model.
        d: MuJoCo Warp data.
        device: Warp device of ``m`` and ``d`` (``"cpu"``, ``"cuda:0"``, ...).
        enabled: False runs ``fn`` directly on every call (the uncaptured path).
    """

    def __init__(self, fn: Callable[[Any, Any], None], m: Any, d: Any, device: str, enabled: bool = True):
        self.fn, self.m, self.d = fn, m, d
        self.device = wp.get_device(device)
        self.enabled = enabled
        self.graph = None
        self.calls = 0
        self.captures = 0
        self.error: str | None = None
        """Why capturing failed, if it did (``enabled`` is then False)."""
        self.direct = False
        """Launch the phase's kernels on every call, counting nothing (set inside an outer capture)."""
        self._stream = wp.Stream(self.device) if self.device.is_cuda else None

    def invalidate(self) -> None:
        """Forget the graph (an array it reads was replaced): the next call captures again."""
        self.graph = None
        self.calls = 0

    def __call__(self, torch_stream: Any = None) -> None:
        """Run the phase: directly (first call, or disabled), else from the graph.

        Args:
            torch_stream: on CUDA, the ``wp.Stream`` of torch's current stream (``wp.stream_from_torch``): the
                graph starts after the work queued there and that stream's later work waits for the graph.
        """
        if self.direct:
            self.fn(self.m, self.d)
            return
        self.calls += 1
        if not self.enabled or self.calls == 1:
            self.fn(self.m, self.d)
            return
        stream = self._stream
        if stream is not None and torch_stream is not None:
            stream.wait_stream(torch_stream)
        if self.graph is None:
            try:
                with wp.ScopedStream(stream), wp.ScopedCapture(device=self.device, stream=stream,
                                                               force_module_load=False) as cap:
                    self.fn(self.m, self.d)
            except Exception as err:  # noqa: BLE001 - a capture that fails must not stop the simulation
                self.enabled, self.error = False, f"{type(err).__name__}: {err}"
                warnings.warn(f"capturing {getattr(self.fn, '__name__', self.fn)} failed ({self.error}); "
                              "its kernels are launched one by one from now on", RuntimeWarning, stacklevel=2)
                self.fn(self.m, self.d)
                if stream is not None and torch_stream is not None:
                    torch_stream.wait_stream(stream)
                return
            self.graph = cap.graph
            self.captures += 1
        wp.capture_launch(self.graph, stream=stream)
        if stream is not None and torch_stream is not None:
            torch_stream.wait_stream(stream)
