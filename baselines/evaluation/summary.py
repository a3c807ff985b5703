"""The statistics of a group of episodes: ``summarize``, the one summary that the
evaluator's table (``aggregate``), the ladder's rungs and the channel sweep all read.

A group is one policy's episodes on one case: rows of ``baselines.evaluation.episode_row``,
fresh or read back from ``episodes.csv``. Rates count the episodes within the current's
reach, with Wilson 95% intervals; means come with seeded bootstrap 95% intervals
(``baselines.stats``); decision times pool every decision of the episodes.

May import: the standard library, numpy, ``baselines.stats``, ``baselines.evaluation.episode_row``
(the error's end) and ``uvms_env`` (the metric, constraint and episode-end names, the
decision-time summary).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from baselines.evaluation.episode_row import ERROR_END
from baselines.stats import bootstrap_mean_interval, wilson_interval
from uvms_env.episode import decision_time_summary
from uvms_env.task.constraints import CONSTRAINTS
from uvms_env.task.metrics import GRADED, HEAD, TAIL
from uvms_env.task.rules import EPISODE_ENDS

Row = dict[str, Any]

VIOLATION_KINDS = CONSTRAINTS
END_KINDS = (*EPISODE_ENDS, ERROR_END)  # how the episodes of a summary ended
#: Rates with Wilson intervals: success, clean success and clean success in the band.
RATES = ("success", "clean_success", "clean_success_tol")
# the episode's numeric totals averaged with bootstrap intervals (same names as the env's);
# the rates are counted, the per-kind values summarized in ``graded``
NOT_AVERAGED = (*RATES, "violation_periods")
MEAN_METRICS = tuple(m for m in (*HEAD, *TAIL) if m not in NOT_AVERAGED)
TIMING = ("median", "p95", "max")
# what the evaluator's table leaves out of ``summarize``: the ladder's counts and median
NOT_TABULATED = (*RATES, "violation_periods_median")
#: Derived per-episode values (``metric_values``): periods to success over the successes
#: only, or over every episode with a failure counted at its cap (``_imputed``: a price
#: never conditioned on success), and the control effort per second.
DERIVED = ("completion_periods", "completion_periods_imputed", "effort_rate")


def metric_values(rows: Sequence[Row], key: str) -> np.ndarray:
    """``key`` of every row as floats, NaN where a row has none (an episode that did not
    end, an empty cell of episodes.csv), or one of ``DERIVED``: ``completion_periods``
    (periods to success, NaN for an episode that did not succeed),
    ``completion_periods_imputed`` (the same, a failure counted at the episode's cap
    ``max_cycles``) and ``effort_rate`` (control effort per simulated second)."""
    if key in ("completion_periods", "completion_periods_imputed"):
        steps = metric_values(rows, "episode_steps")
        cap = metric_values(rows, "max_cycles") if key.endswith("imputed") else np.nan
        won = np.array([bool(r.get("success")) for r in rows], bool)
        return np.where(won, steps, cap)
    if key == "effort_rate":
        time = metric_values(rows, "sim_time_s")
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(time > 0, metric_values(rows, "control_effort") / time, np.nan)
    return np.array([np.nan if r.get(key) in (None, "") else float(r[key]) for r in rows])


def decision_times(rows: Sequence[Row]) -> dict[str, float | None]:
    """Median, p95 and max over every decision of the episodes; rows read back from
    episodes.csv keep only each episode's own summary: then the median of the episodes'
    medians and p95s, and the largest max. None each without a decision."""
    ms = np.concatenate([np.asarray(r.get("_decision_ms", []), float) for r in rows] or [[]])
    pooled = decision_time_summary(ms)
    if pooled is not None:
        return pooled
    medians = metric_values(rows, "policy_time_ms_median")
    if not np.isfinite(medians).any():
        return dict.fromkeys(TIMING)
    maxima = metric_values(rows, "policy_time_ms_max")
    return {
        "median": float(np.nanmedian(medians)),
        "p95": float(np.nanmedian(metric_values(rows, "policy_time_ms_p95"))),
        "max": float(np.nanmax(maxima)) if np.isfinite(maxima).any() else None,
    }


def interventions(rows: Sequence[Row]) -> dict[str, float | None]:
    """The safety filter's share of decisions it changed by more than its tolerance, and
    its mean change, pooled over the episodes' filtered decisions (None: no filter)."""
    decided = sum(r.get("filtered_decisions") or 0 for r in rows)
    if not decided:
        return {"intervention_rate": None, "intervention_mean": None}
    changed = sum(r.get("interventions") or 0 for r in rows)
    deviation = sum(
        (r.get("intervention_mean") or 0.0) * (r.get("filtered_decisions") or 0) for r in rows
    )
    return {"intervention_rate": changed / decided, "intervention_mean": deviation / decided}


def summarize(
    rows: Sequence[Row],
    seed: int,
    means: Sequence[str] = MEAN_METRICS,
    *,
    within_reach_only: bool = False,
) -> Row:
    """One policy's episodes on one case (rows of one policy and scenario):

    * ``policy``, ``information``, ``scenario``; ``episodes``, ``out_of_reach`` (episodes
      whose current is beyond the team's reach: no policy's failure) and ``errors``;
    * each of ``RATES`` (success, clean success, clean success within the tolerance band):
      the count, ``_rate`` and Wilson ``_ci95`` over the episodes within reach;
    * each of ``means``: its mean and bootstrap ``_ci95`` (None without a finite value),
      and ``violation_periods_median``, over every episode or, ``within_reach_only``,
      those within reach (the ladder compares rungs on the episodes they can win);
    * ``graded``: per constraint kind the mean of each graded measure (excess, largest
      excess, violated fraction) and the violation periods summed;
    * ``violations`` (the total per constraint), ``episode_ends`` (how many ended each
      way, ``END_KINDS``; None for rows that do not record it, as older episodes.csv
      files), ``intervention_rate`` and ``intervention_mean`` (``interventions``) and
      ``policy_time_ms`` (``decision_times``), over every episode.
    """
    reach = [r for r in rows if r.get("current_within_reach", True)]
    n = len(reach)
    out: Row = {
        "policy": rows[0]["policy"],
        "information": rows[0].get("information", "local"),
        "scenario": rows[0]["scenario"],
        "episodes": len(rows),
        "out_of_reach": len(rows) - n,
        "errors": sum(bool(r.get("error")) for r in rows),
    }
    for name in RATES:
        k = sum(bool(r.get(name)) for r in reach)
        out[name] = k
        out[f"{name}_rate"] = k / n if n else float("nan")
        out[f"{name}_ci95"] = list(wilson_interval(k, n))
    counted = reach if within_reach_only else rows
    for key in means:  # None each without a finite value
        values = metric_values(counted, key)
        finite = np.isfinite(values).any()
        out[key] = float(np.nanmean(values)) if finite else None
        out[f"{key}_ci95"] = list(bootstrap_mean_interval(values, seed=seed)) if finite else None
    periods = metric_values(counted, "violation_periods")
    periods = periods[np.isfinite(periods)]
    # the typical episode beside the mean, which a few run-aways dominate
    out["violation_periods_median"] = float(np.median(periods)) if len(periods) else None
    out["violations"] = {
        kind: int(sum(r.get(f"violations_{kind}", 0) or 0 for r in rows))
        for kind in VIOLATION_KINDS
    }
    out["graded"] = {
        kind: {g: _mean(metric_values(counted, f"{g}_{kind}")) for g in GRADED}
        for kind in VIOLATION_KINDS
    }
    ends = [r.get("episode_end") for r in rows]
    out["episode_ends"] = {kind: ends.count(kind) for kind in END_KINDS} if all(ends) else None
    out.update(interventions(rows))
    out["policy_time_ms"] = decision_times(rows)
    return out


def _mean(values: np.ndarray) -> float | None:
    return float(np.nanmean(values)) if np.isfinite(values).any() else None


def groups(rows: Sequence[Row]) -> dict[tuple[str, str], list[Row]]:
    """The rows by (policy, scenario), in the rows' order: the groups ``summarize`` takes."""
    out: dict[tuple[str, str], list[Row]] = {}
    for row in rows:
        out.setdefault((row["policy"], row["scenario"]), []).append(row)
    return out


def aggregate(rows: Sequence[Row], seed: int) -> list[Row]:
    """The evaluator's table: ``summarize`` per (policy, scenario), sorted by both, less
    ``NOT_TABULATED`` and the metrics without a finite value."""
    out = []
    for _, group in sorted(groups(rows).items()):
        summary = summarize(group, seed)
        gaps = {k for k in MEAN_METRICS if summary[k] is None}
        out.append(
            {
                k: v
                for k, v in summary.items()
                if k not in NOT_TABULATED and k.removesuffix("_ci95") not in gaps
            }
        )
    return out


def failures(rows: Sequence[Row]) -> list[Row]:
    """One entry per policy with failed episodes (an error recorded), in the rows' order:
    ``policy``, ``failed``, ``episodes`` and its first failure's ``error``, ``scenario``
    and ``episode``."""
    out: dict[str, Row] = {}
    for r in rows:
        entry = out.setdefault(r["policy"], {"policy": r["policy"], "failed": 0, "episodes": 0})
        entry["episodes"] += 1
        if r.get("error"):
            entry["failed"] += 1
            if "error" not in entry:
                entry.update(error=r["error"], scenario=r["scenario"], episode=r["episode"])
    return [e for e in out.values() if e["failed"]]
