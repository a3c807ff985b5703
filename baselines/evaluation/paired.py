"""Two policies on the same episodes: the paired comparison every table of prices and every
"against the expert" column reads.

For a rung and its reference on one case, over the episodes both played within the
current's reach (never only those both won):

* the rates (success, clean success, clean success within the band): each one's
  difference and the exact McNemar test of the discordant episodes;
* the continuous metrics (``PAIRED_METRICS``): completion periods with a failure counted
  at the episode's cap, the internal wrench's RMS, the control effort per second, the
  graded excess and the return: the mean paired difference with its bootstrap interval,
  the ratio of the means and the Wilcoxon signed-rank test.

``compare_all`` compares many pairs and corrects every p-value of the table by Holm's
method (``p_holm`` beside each ``p``). Reference: docs/evaluation.md, "Paired tests".

May import: the standard library, numpy, ``baselines.stats`` and
``baselines.evaluation.summary``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from baselines.evaluation.summary import RATES, Row, groups, metric_values
from baselines.stats import bootstrap_mean_interval, holm, mcnemar_exact, wilcoxon_paired

#: The continuous metrics a comparison prices: its name in the tables -> the row's key.
#: A ratio of means is given for the positive ones with a scale (``RATIO_METRICS``); the
#: excess (often 0 for the reference) and the return (of either sign) get differences only.
PAIRED_METRICS = {
    "completion periods": "completion_periods_imputed",
    "internal wrench rms": "internal_wrench_rms",
    "effort per second": "effort_rate",
    "excess": "excess",
    "return": "return",
}
RATIO_METRICS = ("completion periods", "internal wrench rms", "effort per second")


def paired_episodes(
    rows: Sequence[Row], rung: str, reference: str, case: str
) -> tuple[list[Row], list[Row]]:
    """The rows of ``rung`` and ``reference`` on ``case`` for the episodes both played
    within reach, in episode order."""
    by = groups(rows)
    mine, ref = ({r["episode"]: r for r in by.get((p, case), [])} for p in (rung, reference))
    keys = sorted(
        k
        for k in mine.keys() & ref.keys()
        if mine[k].get("current_within_reach", True) and ref[k].get("current_within_reach", True)
    )
    return [mine[k] for k in keys], [ref[k] for k in keys]


def compare(rows: Sequence[Row], rung: str, reference: str, case: str, seed: int) -> Row:
    """``rung`` against ``reference`` on ``case`` (module docstring): ``episodes`` paired,
    per rate ``{difference, a_only, b_only, p}``, per metric ``{difference,
    difference_ci95, ratio, p, pairs}`` (None without a finite pair)."""
    a, b = paired_episodes(rows, rung, reference, case)
    out: Row = {"rung": rung, "reference": reference, "scenario": case, "episodes": len(a)}
    for name in RATES:
        x = [bool(r.get(name)) for r in a]
        y = [bool(r.get(name)) for r in b]
        test = mcnemar_exact(x, y)
        difference = (sum(x) - sum(y)) / len(a) if a else None
        out[name] = {"difference": difference, **test}
    for name, key in PAIRED_METRICS.items():
        x, y = metric_values(a, key), metric_values(b, key)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            out[name] = None
            continue
        diff = x[ok] - y[ok]
        ref_mean = float(y[ok].mean())
        out[name] = {
            "difference": float(diff.mean()),
            "difference_ci95": list(bootstrap_mean_interval(diff, seed=seed)),
            "ratio": float(x[ok].mean()) / ref_mean
            if name in RATIO_METRICS and ref_mean > 0
            else None,
            **wilcoxon_paired(x[ok], y[ok]),
        }
    return out


def significance_tests(comparison: Row) -> list[dict[str, Any]]:
    """The test dicts of one comparison (each with its ``p``), in a fixed order."""
    parts = [comparison[name] for name in (*RATES, *PAIRED_METRICS)]
    return [t for t in parts if t is not None]


def compare_all(
    rows: Sequence[Row], pairs: Sequence[tuple[str, str]], cases: Sequence[str], seed: int
) -> list[Row]:
    """``compare`` of each (rung, reference) on each case where both played, with every
    p-value of the whole table Holm-corrected (``p_holm``)."""
    played = groups(rows)
    out = [
        compare(rows, rung, ref, case, seed)
        for case in cases
        for rung, ref in pairs
        if (rung, case) in played and (ref, case) in played
    ]
    tests = [t for c in out for t in significance_tests(c)]
    for test, adjusted in zip(tests, holm([t["p"] for t in tests]), strict=True):
        test["p_holm"] = adjusted
    return out
