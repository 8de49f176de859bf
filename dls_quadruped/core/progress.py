"""Progress of long work: a bar with an ETA on a terminal, a line every ~15 s in a log.

Every loop that can run longer than ~10 s (episode rollouts, the closed loop, distillation rounds,
experiment cells, benchmarks) reports through this one function, so they all look and behave alike:

    from dls_quadruped.core.progress import progress, label

    for step in progress(range(num_steps), desc="episodes", unit="step"):
        ...                                        # or, without an iterable:
    with progress(total=num_cells, desc="cells", unit="cell") as bar:
        for cell in cells:
            run(cell)
            bar.update(1)                          # bar.set_postfix_str("cell 3: naive", refresh=False)

    with label("eval survival"):                   # prefixes the desc of every bar opened inside
        evaluate(...)                              # "eval survival: episodes 120/750 ..."

``progress(iterable=None, *, total=None, desc="", unit="it", leave=True, file=None, interval_s=None)``
returns an object with tqdm's core API -- iteration, ``update(n=1)``, ``set_postfix_str(text,
refresh=False)``, ``close()``, use as a context manager, attributes ``n`` and ``total`` -- chosen by
where it writes (``file``, default ``sys.stderr``):

* a terminal: a ``tqdm`` bar (elapsed, ETA, rate), ``leave=False`` erases it when done (inner loops);
* anything else (CI logs, a file, a pipe): :class:`LineProgress`, silent for ``interval_s`` seconds
  (default 15, or ``DLS_PROGRESS_INTERVAL_S``), then one line per interval, e.g.
  ``[progress] eval survival: episodes 120/750 step (16 %), 0:12 elapsed, ETA 1:03``, and a last
  ``... done`` line only if it printed before: work shorter than one interval prints nothing.

``DLS_PROGRESS=bar|lines|off`` forces the mode (``off``: nothing at all, e.g. in tests).
Progress goes to stderr; stdout stays for results. ``tqdm`` is a dependency for the terminal bar
(and its time formatting): well kept, and nothing here re-implements a bar.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Self, TextIO

from tqdm import tqdm

DEFAULT_INTERVAL_S = 15.0
"""Seconds between two lines when not on a terminal (DLS_PROGRESS_INTERVAL_S overrides)."""
MODES = ("bar", "lines", "off")

_LABEL: contextvars.ContextVar[str] = contextvars.ContextVar("dls_progress_label", default="")


@contextlib.contextmanager
def label(text: str) -> Iterator[None]:
    """Prefix ``text`` to the description of every bar opened inside (nested labels join with ': ')."""
    outer = _LABEL.get()
    token = _LABEL.set(f"{outer}: {text}" if outer else text)
    try:
        yield
    finally:
        _LABEL.reset(token)


def _mode(file: TextIO) -> str:
    forced = os.environ.get("DLS_PROGRESS", "").strip().lower()
    if forced:
        if forced not in MODES:
            raise ValueError(f"DLS_PROGRESS must be one of {list(MODES)}, got {forced!r}")
        return forced
    isatty = getattr(file, "isatty", None)
    return "bar" if isatty is not None and isatty() else "lines"


def _interval_s() -> float:
    text = os.environ.get("DLS_PROGRESS_INTERVAL_S")
    if text is None:
        return DEFAULT_INTERVAL_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"DLS_PROGRESS_INTERVAL_S must be a number of seconds > 0, got {text!r}")
    return value


class LineProgress:
    """tqdm's core API, written as a line every ``interval_s`` seconds (for logs, not terminals).

    Args:
        iterable: items to yield (its ``len`` is the total when it has one).
        total: number of units (None: unknown; no percentage or ETA then).
        desc: what is counted, e.g. "episodes".
        unit: unit name, e.g. "step".
        file: where the lines go.
        interval_s: seconds of silence before the first line and between lines.
        clock: seconds, monotonic (``time.monotonic``; a fake one in tests).
    """

    def __init__(self, iterable: Iterable | None = None, total: float | None = None, desc: str = "", unit: str = "it",
                 file: TextIO | None = None, interval_s: float = DEFAULT_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc, unit
        self.file = file if file is not None else sys.stderr
        self.interval_s, self._clock = interval_s, clock
        self.n = 0
        self.postfix = ""
        self._start = self._last = clock()
        self._printed = False
        self._closed = False

    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError("this progress has no iterable; call update(n) instead")
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return int(self.total or 0)

    def set_postfix_str(self, text: str = "", refresh: bool = False) -> None:
        """Text shown after the counts in the next line (``refresh`` is accepted for tqdm's API)."""
        self.postfix = text

    def update(self, n: float = 1) -> None:
        """Count ``n`` more units; print a line if ``interval_s`` has passed since the last one."""
        self.n += n
        now = self._clock()
        if now - self._last >= self.interval_s:
            self._last = now
            self._write(self.line(now))

    def line(self, now: float) -> str:
        """The progress line at time ``now``: counts, percentage, elapsed and remaining time."""
        elapsed = now - self._start
        text = f"[progress] {self.desc + ': ' if self.desc else ''}{self.n:g}"
        if self.total:
            text += f"/{self.total:g} {self.unit} ({100.0 * self.n / self.total:.0f} %)"
        else:
            text += f" {self.unit}"
        text += f", {tqdm.format_interval(elapsed)} elapsed"
        if self.total and 0 < self.n < self.total:
            # ETA = remaining units x mean time per unit so far
            text += f", ETA {tqdm.format_interval((self.total - self.n) * elapsed / self.n)}"
        return text + (f", {self.postfix}" if self.postfix else "")

    def close(self) -> None:
        """End: a last line ``... done`` if this progress printed any line before (else nothing)."""
        if self._closed:
            return
        self._closed = True
        if self._printed:
            self._write(self.line(self._clock()) + ", done")

    def _write(self, text: str) -> None:
        self._printed = True
        print(text, file=self.file, flush=True)


class _Off(LineProgress):
    """Counts, prints nothing (``DLS_PROGRESS=off``)."""

    def _write(self, text: str) -> None:
        pass


def progress(iterable: Iterable | None = None, *, total: float | None = None, desc: str = "", unit: str = "it",
             leave: bool = True, file: TextIO | None = None, interval_s: float | None = None) -> Any:
    """A progress reporter for a loop (module docstring): a tqdm bar on a terminal, lines otherwise.

    Args:
        iterable: items to iterate over (or None and call ``update``).
        total: units of work (default ``len(iterable)`` where it has one).
        desc: what is counted, prefixed by the enclosing :func:`label`\\ s.
        unit: unit name ("step", "episode", "cell", ...).
        leave: keep the bar on the terminal when done (False for inner loops).
        file: stream (default ``sys.stderr``); its ``isatty()`` picks the mode.
        interval_s: seconds between lines off a terminal (default ``DLS_PROGRESS_INTERVAL_S`` or 15).

    Returns:
        ``tqdm`` or :class:`LineProgress`, both with iteration, ``update``, ``set_postfix_str``,
        ``close`` and the context-manager protocol.
    """
    file = file if file is not None else sys.stderr
    prefix = _LABEL.get()
    desc = f"{prefix}: {desc}" if prefix and desc else (prefix or desc)
    mode = _mode(file)
    if mode == "bar":
        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=file, dynamic_ncols=True)
    cls = LineProgress if mode == "lines" else _Off
    return cls(iterable, total=total, desc=desc, unit=unit, file=file,
               interval_s=_interval_s() if interval_s is None else interval_s)
