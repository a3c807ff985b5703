"""Every confidence interval and test of the project, on scipy and rliable: Wilson for
rates, percentile bootstrap for means, Student t bands for learning curves over training
seeds, rliable's IQM and mean over (seeds x cases) tables with stratified bootstrap
intervals; paired tests of two policies on the same episodes (exact McNemar for rates,
Wilcoxon signed-rank for continuous metrics) and Holm's correction within a table. All
seeded, so that a table is reproducible.

Holm's step-down correction is written here (six lines): scipy offers only the
false-discovery-rate controls (``scipy.stats.false_discovery_control``), and statsmodels,
which has it, would be a dependency for one function.

May import: numpy, scipy and rliable (imported on use: only ``baselines.seeds`` needs it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

LEVEL = 0.95
BOOTSTRAP_REPS = 2000


def wilson_interval(successes: int, trials: int, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval of a binomial rate (well-behaved at 0 and 1, small n)."""
    if trials <= 0:
        return (float("nan"), float("nan"))
    ci = stats.binomtest(int(successes), int(trials)).proportion_ci(level, method="wilson")
    return (float(ci.low), float(ci.high))


def bootstrap_mean_interval(
    values: np.ndarray, n_resamples: int = BOOTSTRAP_REPS, level: float = LEVEL, seed: int = 0
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of the finite ``values``."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return (float("nan"), float("nan"))
    if len(x) == 1 or np.all(x == x[0]):  # every resample has the same mean
        return (float(x[0]), float(x[0]))
    res = stats.bootstrap(
        (x,),
        np.mean,
        n_resamples=n_resamples,
        confidence_level=level,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return (float(res.confidence_interval.low), float(res.confidence_interval.high))


def t_band(table: np.ndarray, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray]:
    """Mean and t-interval half-width per column of ``table`` (runs x points, NaN where a
    run has no value); the half-width is 0 where fewer than two runs have one."""
    n = np.sum(np.isfinite(table), axis=0)
    mean = np.nanmean(table, axis=0)
    sd = np.nanstd(table, axis=0, ddof=1) if len(table) > 1 else np.zeros_like(mean)
    half = stats.t.ppf(0.5 + level / 2, np.maximum(n - 1, 1)) * sd / np.sqrt(np.maximum(n, 1))
    return mean, np.where(n > 1, half, 0.0)


def iqm_and_mean(table: np.ndarray, seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """IQM and mean of a (seeds x cases) table, each (point, low, high) with a stratified
    bootstrap interval (rliable)."""
    from rliable import library as rly
    from rliable import metrics

    def both(scores: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(scores), metrics.aggregate_mean(scores)])

    # rliable's stratified resampling draws from numpy's global generator whatever
    # random_state says (two calls gave two intervals): seed it, then put it back
    saved = np.random.get_state()  # noqa: NPY002 (the library's global state)
    np.random.seed(seed)  # noqa: NPY002
    try:
        point, interval = rly.get_interval_estimates(
            {"group": table},
            both,
            reps=BOOTSTRAP_REPS,
            confidence_interval_size=LEVEL,
            random_state=np.random.RandomState(seed),
        )
    finally:
        np.random.set_state(saved)  # noqa: NPY002
    p, ci = point["group"], interval["group"]
    return {
        "iqm": (float(p[0]), float(ci[0, 0]), float(ci[1, 0])),
        "mean": (float(p[1]), float(ci[0, 1]), float(ci[1, 1])),
    }


def mcnemar_exact(a: Sequence[bool], b: Sequence[bool]) -> dict[str, float]:
    """Exact McNemar test of paired outcomes ``a`` and ``b`` (the same episodes): the
    two-sided binomial test of the discordant pairs. ``a_only``/``b_only``: the episodes
    only one of them won; ``p`` is 1 without a discordant pair."""
    x, y = np.asarray(a, bool), np.asarray(b, bool)
    if x.shape != y.shape:
        raise ValueError(f"paired outcomes differ in length: {x.shape} and {y.shape}")
    a_only, b_only = int(np.sum(x & ~y)), int(np.sum(~x & y))
    n = a_only + b_only
    p = stats.binomtest(a_only, n, 0.5).pvalue if n else 1.0
    return {"a_only": a_only, "b_only": b_only, "p": float(p)}


def wilcoxon_paired(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    """Wilcoxon signed-rank test of paired values (the same episodes, NaN pairs dropped):
    the median difference a - b, the pairs used and the two-sided ``p`` (1 when every
    difference is zero or fewer than two pairs remain)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    if x.shape != y.shape:
        raise ValueError(f"paired values differ in length: {x.shape} and {y.shape}")
    ok = np.isfinite(x) & np.isfinite(y)
    d = x[ok] - y[ok]
    out = {"pairs": int(ok.sum()), "median_difference": float(np.median(d)) if len(d) else np.nan}
    if len(d) < 2 or not np.any(d != 0):
        return {**out, "p": 1.0}
    return {**out, "p": float(stats.wilcoxon(d, zero_method="wilcox").pvalue)}


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values (same order as given; NaN stays NaN): the k-th
    smallest of m is multiplied by m - k + 1, then made monotone and capped at 1."""
    p = np.asarray(pvalues, float)
    out = np.full(p.shape, np.nan)
    idx = np.flatnonzero(np.isfinite(p))
    order = idx[np.argsort(p[idx], kind="stable")]
    m = len(order)
    adjusted = np.maximum.accumulate(p[order] * (m - np.arange(m)))
    out[order] = np.minimum(adjusted, 1.0)
    return out.tolist()
