"""``sync_probe``: count the host reads of tensor data and the host-to-device uploads a block of code makes.

On a GPU every read of device memory by the host (``t.item()``, ``bool(t)``, ``if t.any():``, ``t.tolist()``,
``torch.nonzero``, a boolean-mask index) waits for every kernel queued before it, and every tensor built from
Python numbers or numpy (``torch.tensor(0.5, device=dev)``) is a copy from the host. Inside a simulation step
both stall the pipeline. The probe finds them on any device, the CPU included, by wrapping the torch entry
points that do them while the block runs, and records each call under the site that made it: the innermost
frame inside ``package`` (``path/file.py:function:line``, path relative to the package's parent).

Counted (``kind``): ``item``, ``cpu``, ``numpy``, ``tolist``, ``__bool__``, ``__int__``, ``__float__``,
``__index__``, ``__array__`` (host reads of a tensor's values); ``nonzero`` (``torch.nonzero``,
``Tensor.nonzero``: its output size is read back); ``upload`` (``torch.as_tensor``, ``torch.tensor``,
``torch.from_numpy`` of numpy arrays, Python lists or scalars). A call nested in a counted one (``__array__`` calls
``numpy``) counts once.

Not seen: reads made inside C++ or another library without a Python call to these entry points
(``.to("cpu")``, ``torch.equal``), and boolean-mask indexing ``t[mask]`` (wrapping ``__getitem__`` on
the tensor type would leave a sequence slot behind that turns 0-d tensors into sequences). On CUDA,
``torch.cuda.set_sync_debug_mode("warn")`` sees those too; the probe is for code review and tests on machines without a
GPU.

Usage::

    with sync_probe() as report:
        env.step(actions)
    report.by_site()   # {"dls_quadruped/envs/env.py:_finish_step:171 nonzero": 1, ...}
"""

from __future__ import annotations

import os
import sys
import threading
from collections import Counter
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import torch

import dls_quadruped

READ_METHODS = ("item", "cpu", "numpy", "tolist", "__bool__", "__int__", "__float__", "__index__", "__array__",
                "nonzero")
"""``torch.Tensor`` methods counted as host reads."""
UPLOAD_FUNCTIONS = ("as_tensor", "tensor", "from_numpy")
"""``torch`` functions counted as uploads when given data that is not already a tensor."""


@dataclass(frozen=True)
class SyncSite:
    """Where a counted call came from: ``file`` relative to the package's parent, ``function``, ``line``."""

    file: str
    function: str
    line: int
    kind: str

    def key(self) -> str:
        """``file:function`` (line-free, so an allow-list survives edits above the call)."""
        return f"{self.file}:{self.function}"

    def __str__(self) -> str:
        return f"{self.file}:{self.function}:{self.line} {self.kind}"


@dataclass
class SyncReport:
    """Counts of one probe, by site (:class:`SyncSite`)."""

    counts: Counter = field(default_factory=Counter)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def by_site(self) -> dict[str, int]:
        """{``"file:function:line kind"``: count}, most frequent first."""
        return {str(s): n for s, n in self.counts.most_common()}

    def outside(self, allowed: Iterable[str]) -> dict[str, int]:
        """:meth:`by_site` without the sites whose ``file:function`` is in ``allowed``."""
        allowed = set(allowed)
        return {str(s): n for s, n in self.counts.most_common() if s.key() not in allowed}


class _Probe:
    """The wrapped entry points (installed while at least one probe is active) and the active reports."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.reports: list[tuple[SyncReport, str, tuple[str, ...]]] = []
        self.saved: dict[tuple[object, str], object] = {}
        self.local = threading.local()
        self.persistent = False  # keep_installed(): the wrappers stay when the last probe ends

    def record(self, kind: str) -> None:
        for report, root, exclude in self.reports:
            frame = sys._getframe(2)
            while frame is not None and not frame.f_code.co_filename.startswith(root + os.sep):
                frame = frame.f_back
            if frame is None:
                continue
            rel = Path(frame.f_code.co_filename).relative_to(Path(root).parent).as_posix()
            if rel in exclude:
                continue
            report.counts[SyncSite(rel, frame.f_code.co_name, frame.f_lineno, kind)] += 1

    def _wrap(self, owner: object, name: str, kind: str, counts) -> None:
        original = getattr(owner, name)
        self.saved[(owner, name)] = owner.__dict__.get(name, _MISSING)
        probe = self

        def wrapper(*args, **kwargs):
            if torch.compiler.is_compiling():
                # dynamo traces this wrapper while compiling a function that calls the entry point: what it
                # traces runs inside the compiled graph, not as a host read or upload, and frame walking
                # (sys._getframe) cannot be traced. A graph break runs its eager part here again, counted.
                return original(*args, **kwargs)
            if getattr(probe.local, "depth", 0) == 0 and counts(args, kwargs):
                probe.record(kind)
            probe.local.depth = getattr(probe.local, "depth", 0) + 1
            try:
                return original(*args, **kwargs)
            finally:
                probe.local.depth -= 1

        wrapper.__name__ = name
        setattr(owner, name, wrapper)

    def install(self) -> None:
        def always(args, kwargs):
            return True

        def not_a_tensor(args, kwargs):
            data = args[0] if args else kwargs.get("data", kwargs.get("ndarray"))
            return not isinstance(data, torch.Tensor)

        for name in READ_METHODS:
            self._wrap(torch.Tensor, name, name, always)
        self._wrap(torch, "nonzero", "nonzero", always)
        for name in UPLOAD_FUNCTIONS:
            self._wrap(torch, name, "upload", not_a_tensor)

    def uninstall(self) -> None:
        for (owner, name), saved in self.saved.items():
            if saved is _MISSING:
                delattr(owner, name)
            else:
                setattr(owner, name, saved)
        self.saved.clear()


_MISSING = object()
_PROBE = _Probe()


@contextmanager
def sync_probe(package: str | Path | None = None, exclude: Iterable[str] = ()) -> Iterator[SyncReport]:
    """Count host reads and uploads made while the block runs (module doc); yields the :class:`SyncReport`.

    Args:
        package: the source folder whose innermost frame names a site (default ``dls_quadruped``'s); calls
            with no frame inside it are not counted.
        exclude: files (relative to the package's parent, e.g. ``"dls_quadruped/sim/cpu_backend.py"``) whose calls
            are not counted: code that moves data to the host by design.

    Probes nest (each counts what happens while it is active); the wrappers are removed when the last one ends.
    """
    root = str(Path(package or Path(dls_quadruped.__file__).parent).resolve())
    report = SyncReport()
    entry = (report, root, tuple(exclude))
    with _PROBE.lock:
        if not _PROBE.saved:
            _PROBE.install()
        _PROBE.reports.append(entry)
    try:
        yield report
    finally:
        with _PROBE.lock:
            _PROBE.reports.remove(entry)
            if not _PROBE.reports and not _PROBE.persistent:
                _PROBE.uninstall()


def keep_installed(keep: bool = True) -> None:
    """Install the probe's wrappers now and keep them for the rest of the process (they count only while a
    :func:`sync_probe` is active); ``keep=False`` ends that (the wrappers go when no probe is active).

    For probing compiled code: dynamo guards a compiled function on the identity of some torch functions it
    traced (torch 2.11 on ``torch.tensor`` and ``torch.as_tensor``, e.g. in a cached constant's builder). Wrappers
    installed only while a probe is active swap those objects, so every compiled function would recompile inside
    the probe, and what the recompile runs would be counted as the step's. Call this before the functions are
    compiled: they then guard on the wrappers, which stay."""
    with _PROBE.lock:
        _PROBE.persistent = keep
        if keep and not _PROBE.saved:
            _PROBE.install()
        elif not keep and not _PROBE.reports:
            _PROBE.uninstall()
