"""Statistics of evaluation episodes: pure numpy functions, each with its sample count and 95 % interval.

Shapes: E episodes, T policy steps. ``valid`` masks mark the steps whose state belongs to the
episode (before its termination).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from dls_quadruped.core.stats import Z95, wilson_interval


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


def binomial(successes: int, n: int) -> dict:
    """A proportion with its 95 % Wilson interval and counts: {rate, ci95, k, n}."""
    lo, hi = wilson_interval(int(successes), int(n))
    return {"rate": successes / n if n else math.nan, "ci95": [lo, hi], "k": int(successes), "n": int(n)}


def grouped_rate(success: np.ndarray, group: np.ndarray, num_groups: int) -> list[dict]:
    """``binomial`` of the boolean ``success`` (E,) within each group 0..num_groups-1 of ``group`` (E,)."""
    success, group = np.asarray(success, dtype=bool), np.asarray(group)
    return [binomial(int(success[group == g].sum()), int((group == g).sum())) for g in range(num_groups)]


def grouped_mean(values: np.ndarray, group: np.ndarray, num_groups: int) -> list[dict]:
    """``mean_ci`` of the finite ``values`` (E,) within each group."""
    values, group = np.asarray(values, dtype=float), np.asarray(group)
    return [mean_ci(values[group == g]) for g in range(num_groups)]


def threshold_crossing(levels: np.ndarray, rates: np.ndarray, threshold: float, outermost: bool = False) -> float:
    """Where a rate that should fall with the level drops below ``threshold``.

    ``levels`` ascending (M,), ``rates`` (M,). Default: at the *first* level below ``threshold``;
    ``outermost``: after the *last* level at or above it (the edge of the region where the rate is
    high, ignoring failures at low levels). Returns the level interpolated linearly between that
    level at or above and the next one; ``levels[-1]`` if there is no level below after it (the
    crossing is beyond the grid) and ``levels[0]`` if none before it is at or above (before it).
    """
    levels, rates = np.asarray(levels, dtype=float), np.asarray(rates, dtype=float)
    high = rates >= threshold  # NaN counts as below
    if outermost:
        above = np.nonzero(high)[0]
        if above.size == 0:
            return float(levels[0])
        j = int(above[-1]) + 1
        if j == len(levels):
            return float(levels[-1])
    else:
        below = np.nonzero(~high)[0]
        if below.size == 0:
            return float(levels[-1])
        j = int(below[0])
        if j == 0:
            return float(levels[0])
    l0, l1, r0, r1 = levels[j - 1], levels[j], rates[j - 1], rates[j]
    r1 = 0.0 if not np.isfinite(r1) else r1
    return float(l0 + (r0 - threshold) / (r0 - r1) * (l1 - l0))  # r0 >= thr > r1: on the segment


def crossing_interval(levels: np.ndarray, successes: np.ndarray, n: np.ndarray, threshold: float,
                      draws: int = 2000, seed: int = 0, outermost: bool = False) -> list[float]:
    """95 % interval of ``threshold_crossing`` by posterior simulation: every level's rate drawn
    from its Jeffreys posterior Beta(k + 1/2, n - k + 1/2), the crossing recomputed, its 2.5 and
    97.5 percentiles. Unlike resampling from k / n, a level seen at 0 % or 100 % is not treated
    as certain (that collapses the interval to a point whatever n), and unlike a shrunk k / n it
    does not pull 16/16 down onto a 90 % threshold. A first-drop crossing over many levels near
    100 % is honestly uncertain at its low end: any of them may be below the threshold."""
    rng = np.random.default_rng(seed)
    k, n = np.asarray(successes, dtype=float), np.asarray(n, dtype=float)
    sims = rng.beta(k + 0.5, n - k + 0.5, size=(draws, len(n)))                         # (draws, M)
    values = np.array([threshold_crossing(levels, s, threshold, outermost) for s in sims])
    lo, hi = np.percentile(values, [2.5, 97.5])
    return [float(lo), float(hi)]


def _resample(values: np.ndarray, rng: np.random.Generator, draws: int) -> np.ndarray:
    """(draws, S, E) copies of ``values`` (S, E) with episodes (columns) resampled with replacement, and
    rows (seeds) too when there are several."""
    s, e = values.shape
    cols = rng.integers(0, e, size=(draws, 1, e))
    rows = rng.integers(0, s, size=(draws, s, 1)) if s > 1 else np.zeros((draws, 1, 1), dtype=int)
    return values[rows, cols]


def _as_units(values: np.ndarray) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[None]
    if v.ndim != 2:
        raise ValueError(f"values must be (E,) episodes or (S, E) seeds x episodes, got shape {v.shape}")
    return v


def bootstrap_ci(values: np.ndarray, stat=np.nanmedian, draws: int = 2000, seed: int = 0) -> list[float]:
    """95 % interval of ``stat`` over seeds and episodes: ``values`` (E,) or (S, E) per-episode values of
    S seeds (e.g. sampler seeds) on the same E episodes; a two-level bootstrap resamples the episodes and,
    when S > 1, the seeds, and takes the 2.5 and 97.5 percentiles of ``stat`` of the resampled values
    (NaN values, e.g. episodes without a valid step, are ignored by the nan-statistics)."""
    v = _as_units(values)
    if not np.isfinite(v).any():
        return [math.nan, math.nan]
    boot = _resample(v, np.random.default_rng(seed), draws).reshape(draws, -1)
    with np.errstate(all="ignore"):
        stats = np.array([stat(b) for b in boot])
    stats = stats[np.isfinite(stats)]
    if stats.size == 0:
        return [math.nan, math.nan]
    lo, hi = np.percentile(stats, [2.5, 97.5])
    return [float(lo), float(hi)]


def episode_summary(values: np.ndarray, seed: int = 0) -> dict:
    """Per-episode values (E,) or (S, E) -> {median, q1, q3 (across episodes and seeds), ci95 (of the
    median, two-level bootstrap), mean, mean_ci95, n (finite episode values)}."""
    v = _as_units(values)
    flat = v[np.isfinite(v)]
    if flat.size == 0:
        return {"median": math.nan, "q1": math.nan, "q3": math.nan, "ci95": [math.nan, math.nan],
                "mean": math.nan, "mean_ci95": [math.nan, math.nan], "n": 0}
    q1, med, q3 = np.percentile(flat, [25, 50, 75])
    return {"median": float(med), "q1": float(q1), "q3": float(q3), "ci95": bootstrap_ci(v, np.nanmedian, seed=seed),
            "mean": float(flat.mean()), "mean_ci95": bootstrap_ci(v, np.nanmean, seed=seed), "n": int(flat.size)}


def paired_difference(a: np.ndarray, b: np.ndarray, draws: int = 2000, seed: int = 0,
                      paired_seeds: bool = False) -> dict:
    """Paired difference of two controllers (or policies) evaluated on the same E episodes.

    Args:
        a, b: per-episode values, (E,) or (S, E) with S seeds each (S may differ between a and b, e.g. an
            RL policy has no sampler seed). Episode e of ``a`` and of ``b`` must be the same episode.
        paired_seeds: row s of ``a`` and of ``b`` are the same unit (e.g. the same student at two settings):
            the seeds are resampled together, like the episodes (a and b must then have the same S).

    Returns:
        {"mean": mean over episodes of d_e = mean_s a_se - mean_s b_se, "ci95": its 95 % interval (two-level
        bootstrap: episodes resampled together for a and b, seeds independently unless ``paired_seeds``), "relative":
        sum_e d_e / sum_e b_e (e.g. Table 16's delta), "relative_ci95", "median": the median over episodes of d_e
        (robust to a few episodes where one side stumbled) and "median_ci95" (the same resamples), "episodes": episodes
        where both are finite}.
        Episodes where either side has no finite value are left out of both.
    """
    a, b = _as_units(a), _as_units(b)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"a and b must cover the same episodes, got {a.shape[1]} and {b.shape[1]}")
    if paired_seeds and a.shape[0] != b.shape[0]:
        raise ValueError(f"paired_seeds needs the same seeds in a and b, got {a.shape[0]} and {b.shape[0]}")
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an episode without values: NaN, left out below
        keep = np.isfinite(np.nanmean(a, 0)) & np.isfinite(np.nanmean(b, 0))
    a, b = a[:, keep], b[:, keep]
    e = a.shape[1]
    nan2 = [math.nan, math.nan]
    if e == 0:
        return {"mean": math.nan, "ci95": nan2, "relative": math.nan, "relative_ci95": nan2, "median": math.nan,
                "median_ci95": nan2, "episodes": 0}

    def stats(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            # a resample of all-NaN seeds: NaN, dropped from the interval
            warnings.simplefilter("ignore", RuntimeWarning)
            xm, ym = np.nanmean(x, axis=-2), np.nanmean(y, axis=-2)  # per episode, over seeds
            d = xm - ym
            return np.nanmean(d, axis=-1), np.nansum(d, axis=-1) / np.nansum(ym, axis=-1), np.nanmedian(d, axis=-1)

    mean, rel, median = stats(a, b)
    rng = np.random.default_rng(seed)
    cols = rng.integers(0, e, size=(draws, 1, e))
    ra = rng.integers(0, a.shape[0], size=(draws, a.shape[0], 1)) if a.shape[0] > 1 else np.zeros((draws, 1, 1), int)
    rb = rng.integers(0, b.shape[0], size=(draws, b.shape[0], 1)) if b.shape[0] > 1 else np.zeros((draws, 1, 1), int)
    if paired_seeds:
        rb = ra
    bm, br, bmed = stats(a[ra, cols], b[rb, cols])

    def ci(x: np.ndarray) -> list[float]:
        x = x[np.isfinite(x)]
        return [float(v) for v in np.percentile(x, [2.5, 97.5])] if x.size else nan2

    return {"mean": float(mean), "ci95": ci(bm), "relative": float(rel), "relative_ci95": ci(br),
            "median": float(median), "median_ci95": ci(bmed), "episodes": int(e)}
