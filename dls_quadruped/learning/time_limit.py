"""A wall-time budget for a training run (``train --time-limit``): when to stop so that the last iteration, the
closing save and the export end before the limit."""

from __future__ import annotations

import time


class TimeLimitReached(Exception):
    """The next iteration would not end before the deadline; the last finished one was saved to ``path``."""

    def __init__(self, path: str | None, iteration: int):
        self.path, self.iteration = path, iteration
        super().__init__(f"time limit: saved {path} (iteration {iteration})")


clock = time.monotonic
"""The clock of ``Deadline`` and the runner's time checks (a test replaces it)."""


class Deadline:
    """A wall-time budget that started at construction: ``Deadline(seconds)``.

    ``stop_after(iteration_s)`` is True once another iteration of ``iteration_s`` seconds (doubled: the next
    one can be slower, e.g. a checkpoint save or a recompile), plus ``reserve_s`` for the closing save and
    the policy export, would end past the budget.
    """

    def __init__(self, seconds: float, reserve_s: float = 20.0):
        self.seconds, self.reserve_s = float(seconds), float(reserve_s)
        self.start = clock()

    def left(self, now: float | None = None) -> float:
        """Seconds left at ``now`` (default: the clock's now)."""
        return self.start + self.seconds - (clock() if now is None else now)

    def stop_after(self, iteration_s: float, now: float | None = None) -> bool:
        return self.left(now) < 2.0 * iteration_s + self.reserve_s
