"""The binomial interval shared by the eval suite's statistics (``eval/metrics.py``) and the distillation
metrics (``learning/distill_metrics.py``)."""

from __future__ import annotations

import math

Z95 = 1.959963984540054
"""Two-sided 95 % quantile of the standard normal."""


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); stays inside [0, 1] and
    is not degenerate at 0 % or 100 % (unlike the normal approximation)."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1.0 + z * z / n                                              # 1 + z^2/n
    centre = (p + z * z / (2 * n)) / denom                               # (p + z^2/2n) / (1 + z^2/n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom  # z sqrt(p(1-p)/n + z^2/4n^2) / (...)
    # the interval contains p; rounding can put an end a hair past it at 0 % or 100 %
    return (min(max(0.0, centre - half), p), max(min(1.0, centre + half), p))
