"""Per-episode evaluation rows as marl-eval JSON (InstaDeep's ``id-marl-eval`` tools).

marl-eval's statistics and plots (interquartile means, performance profiles, probability
of improvement) read one nested dictionary:

    {env_name: {task_name: {algo_name: {"seed_K": {
        "step_0": {"step_count": int, "elapsed_time": float, metric: [per episode]}, ...,
        "absolute_metrics": {metric: [per episode]}}}}}}

One evaluation of ``baselines.evaluate`` is one logging step of one run: the step holds
the per-episode values of each metric, and ``absolute_metrics`` repeats the latest step
(marl-eval takes the final evaluation of a run from there). Writing into an existing file
merges, so several policies, seeds or training evaluations land in one file, as the
tools expect.

May import: the standard library, numpy and its package's ``ENV_NAME`` (no ray, no torch).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from baselines.distributed import ENV_NAME

# marl-eval averages every list it finds, so only numeric per-episode values; booleans as
# 0/1 so success rates aggregate like returns.
METRICS: tuple[str, ...] = (
    "return",
    "success",
    "clean_success",
    "episode_steps",
    "final_pos_error_m",
    "final_att_error_rad",
    "min_obstacle_clearance_m",
    "violation_periods",
)
ABSOLUTE = "absolute_metrics"


def task_name(scenario: str, overrides: dict[str, Any] | None = None) -> str:
    """``paper``, ``random_n2``: marl-eval compares algorithms per task, and a team size
    is a different task."""
    n = (overrides or {}).get("n_agents")
    return f"{scenario}_n{n}" if n is not None else scenario


def algo_name(policy: str) -> str:
    # marl-eval's probability-of-improvement plots split algorithm lists on commas
    return policy.replace(",", ";")


def metric_value(row: dict[str, Any], metric: str) -> float:
    value = row.get(metric)
    if value is None or value == "":
        return math.nan
    return float(value)


def step_entry(
    rows: Iterable[dict[str, Any]], step_count: int, elapsed_time: float
) -> dict[str, Any]:
    """One logging step. A metric no episode has (``min_obstacle_clearance_m`` without
    obstacles) is left out; one that only some lack (an episode whose policy raised) is
    NaN there, which Python's json, and so marl-eval, reads back as NaN."""
    rows = list(rows)
    entry: dict[str, Any] = {"step_count": int(step_count), "elapsed_time": float(elapsed_time)}
    for metric in METRICS:
        values = [metric_value(r, metric) for r in rows]
        if not all(math.isnan(v) for v in values):
            entry[metric] = values
    return entry


def add_evaluation(
    data: dict[str, Any],
    rows: list[dict[str, Any]],
    seed: int,
    step_count: int = 0,
    elapsed_time: float = 0.0,
    overrides: dict[str, Any] | None = None,
    step: int | None = None,
    env_name: str = ENV_NAME,
) -> dict[str, Any]:
    """Add one evaluation (rows of ``baselines.evaluate``, any policies and scenarios) to
    ``data`` as logging step ``step`` (None: the run's next) of run ``seed_{seed}``, and
    make it the run's ``absolute_metrics``. Returns ``data``."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        key = (task_name(row["scenario"], overrides), algo_name(row["policy"]))
        groups.setdefault(key, []).append(row)
    for (task, algo), group in groups.items():
        group = sorted(group, key=lambda r: r["episode"])
        run = (
            data.setdefault(env_name, {})
            .setdefault(task, {})
            .setdefault(algo, {})
            .setdefault(f"seed_{seed}", {})
        )
        index = step if step is not None else sum(k.startswith("step_") for k in run)
        entry = step_entry(group, step_count, elapsed_time)
        run[f"step_{index}"] = entry
        run[ABSOLUTE] = {m: v for m, v in entry.items() if m in METRICS}
        # the absolute metrics close the run: keep them last, as marl-eval's logger does
        run[ABSOLUTE] = run.pop(ABSOLUTE)
    return data


def write(path: Path, rows: list[dict[str, Any]], seed: int, **kwargs: Any) -> dict[str, Any]:
    """Merge one evaluation into the JSON file at ``path`` (created if missing); see
    ``add_evaluation`` for the keywords. Returns the whole file's data."""
    path = Path(path)
    data = json.loads(path.read_text()) if path.exists() else {}
    add_evaluation(data, rows, seed, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")
    return data
