"""The binomial interval shared by the eval suite's statistics (``eval/metrics.py``) and the distillation
metrics (``learning/distill_metrics.py``), and Student's t quantile for the learning-curve trend
(``viz/learning_curve.py``)."""

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


def t_cdf(x: float, dof: int) -> float:
    """Student's t distribution function with ``dof`` degrees of freedom, by the regularised incomplete beta
    function I_{dof/(dof+x^2)}(dof/2, 1/2) (its continued fraction, Lentz's method)."""
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof}")
    if x == 0.0:
        return 0.5
    z = dof / (dof + x * x)
    tail = 0.5 * _betainc(dof / 2.0, 0.5, z)  # P(T > |x|)
    return 1.0 - tail if x > 0 else tail


def t_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of Student's t with ``dof`` degrees of freedom (bisection on :func:`t_cdf`, to 1e-12)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1), got {p}")
    lo, hi = -1e3, 1e3
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if t_cdf(mid, dof) < p else (lo, mid)
        if hi - lo < 1e-12:
            break
    return 0.5 * (lo + hi)


def _betainc(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta I_x(a, b) for 0 <= x <= 1 (continued fraction; the symmetry
    I_x(a, b) = 1 - I_{1-x}(b, a) where the fraction converges slowly)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = a * math.log(x) + b * math.log1p(-x) - (math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b))
    if x > (a + 1.0) / (a + b + 2.0):
        return 1.0 - _betainc(b, a, 1.0 - x)
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    f = d
    for m in range(1, 500):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            f *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return math.exp(log_front) * f / a
