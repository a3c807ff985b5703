"""Every confidence interval of the project, on scipy and rliable: Wilson for rates,
percentile bootstrap for means, Student t bands for learning curves over training seeds,
and rliable's IQM and mean over (seeds x cases) tables with stratified bootstrap
intervals. All seeded, so that a table is reproducible.

May import: numpy, scipy and rliable (imported on use: only ``baselines.seeds`` needs it).
"""

from __future__ import annotations

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
