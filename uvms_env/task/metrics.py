"""Episode metrics, with the names used everywhere (metrics.json, evaluation tables, README).

``uvms_env.task.rules.Task`` accumulates them over K environments (one for the single
env) and ends in ``episode_result``, whose dict is ``infos[agent]["metrics"]`` when an
episode ends. The expert's main job and the evaluator reuse it (and ``goal_errors``)
instead of recomputing.

The metrics' meanings are tabled once, in docs/options.md, "Episode metrics" (a test
keeps that table and ``METRICS`` in step).

May import: numpy and ``uvms_env.task.constraints``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from uvms_env.task.constraints import CONSTRAINTS

METRICS = (
    "success",
    "clean_success",
    "episode_steps",
    "sim_time_s",
    "final_pos_error_m",
    "final_att_error_rad",
    "min_obstacle_clearance_m",
    "min_manipulability",
    "violations",
    "violation_periods",
    "internal_wrench_rms",
    "control_effort",
    "policy_time_ms",
    "grasp_drift_max_m",
)


def goal_errors(x_o: Sequence[float], goal: Sequence[float]) -> tuple[float, float]:
    """Position error (m) and largest wrapped Euler-angle error (rad) of pose x_O to goal.

    Plain floats (it runs every step): |remainder(a, 2 pi)| is |wrap(a)|."""
    x, g = list(x_o), list(goal)
    pos = math.dist(x[:3], g[:3])
    att = max(abs(math.remainder(a - b, math.tau)) for a, b in zip(x[3:6], g[3:6], strict=True))
    return pos, att


def episode_result(
    period: float,
    steps: int,
    x_o: Sequence[float],
    goal: Sequence[float],
    success: bool,
    min_clearance: float,
    min_manipulability: float,
    violations: Sequence[int],
    wrench_sq: float,
    wrench_samples: int,
    effort: float,
    grasp_drift: float,
    constraints: Sequence[str] = CONSTRAINTS,
) -> dict[str, Any]:
    """The metrics dict of an ended episode from its accumulated quantities (plain Python
    types, JSON-ready): the task's accumulated arrays end here. ``constraints``: the
    names of ``violations``. ``min_clearance`` is inf without obstacles; no wrench sample
    gives None."""
    pos, att = goal_errors(x_o, goal)
    periods = {k: int(v) for k, v in zip(constraints, violations, strict=True)}
    steps, wrench_samples = int(steps), int(wrench_samples)
    clearance = float(min_clearance)
    return {
        "success": bool(success),
        "clean_success": bool(success) and not any(periods.values()),
        "episode_steps": steps,
        "sim_time_s": steps * period,
        "final_pos_error_m": pos,
        "final_att_error_rad": att,
        "min_obstacle_clearance_m": clearance if math.isfinite(clearance) else None,
        "min_manipulability": float(min_manipulability),
        "violations": periods,
        "violation_periods": sum(periods.values()),
        "internal_wrench_rms": (
            math.sqrt(float(wrench_sq) / wrench_samples) if wrench_samples else None
        ),
        "control_effort": float(effort),
        "policy_time_ms": None,
        "grasp_drift_max_m": float(grasp_drift),
    }
