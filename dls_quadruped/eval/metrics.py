"""Statistics of evaluation episodes: pure numpy functions, each with its sample count and 95 % interval.

Shapes: E episodes, T policy steps. ``valid`` masks mark the steps whose state belongs to the
episode (before its termination).
"""

from __future__ import annotations

import math

import numpy as np

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
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_ci(x: np.ndarray) -> dict:
    """Mean of the finite values of ``x`` with a normal-approximation 95 % interval."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return {"mean": math.nan, "ci95": [math.nan, math.nan], "n": 0}
    m = float(x.mean())
    half = Z95 * float(x.std(ddof=1)) / math.sqrt(n) if n > 1 else math.nan
    return {"mean": m, "ci95": [m - half, m + half], "n": n}


def median_iqr(x: np.ndarray) -> dict:
    """Median and quartiles (1st, 3rd) of the finite values of ``x``."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"median": math.nan, "q1": math.nan, "q3": math.nan, "n": 0}
    q1, med, q3 = np.percentile(x, [25, 50, 75])
    return {"median": float(med), "q1": float(q1), "q3": float(q3), "n": int(x.size)}


def linear_fit(x: np.ndarray, y: np.ndarray) -> dict:
    """Least-squares line y = slope x + intercept over the finite pairs, with the slope's 95 %
    interval from its standard error (normal approximation)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = int(x.size)
    sxx = float(((x - x.mean()) ** 2).sum()) if n else 0.0
    if n < 3 or sxx == 0.0:
        return {"slope": math.nan, "intercept": math.nan, "slope_ci95": [math.nan, math.nan], "n": n}
    slope = float(((x - x.mean()) * (y - y.mean())).sum() / sxx)  # cov(x, y) / var(x)
    intercept = float(y.mean() - slope * x.mean())
    resid = y - (slope * x + intercept)
    se = math.sqrt(float((resid ** 2).sum()) / (n - 2) / sxx)      # sqrt(s^2 / Sxx), s^2 = RSS / (n - 2)
    return {"slope": slope, "intercept": intercept, "slope_ci95": [slope - Z95 * se, slope + Z95 * se], "n": n}


def masked_mean(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per-episode mean over the valid steps: x (T, E, ...) and valid (T, E) -> (E, ...); NaN where
    an episode has no valid step."""
    w = valid.astype(float).reshape(valid.shape + (1,) * (x.ndim - valid.ndim))
    count = w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (x * w).sum(axis=0) / np.maximum(count, 1), np.nan)
