"""Episode metrics, with the names used everywhere (the infos, metrics.json, episodes.csv,
the marl-eval JSON, TorchRL's and BenchMARL's logs, the README).

``uvms_env.task.rules.Task`` accumulates them over K environments (one for the single
env) and ends in ``episode_result``: one flat dict of numbers (``metric_keys``), so that
every consumer reads the same names and a tensor library can carry them as they are.
The expert's main job and the evaluator reuse it (and ``goal_errors``) instead of
recomputing.

Per constraint kind (``uvms_env.task.constraints``, the built-in kinds and any extra
ones): ``violations_<kind>`` (periods in which some robot violated it), the graded
``excess_<kind>`` (sum over robot-periods of max(0, g) / scale, divided by the episode's
periods: the mean per period, summed over robots), ``max_excess_<kind>`` (the largest
max(0, g) / scale of any robot in any period) and ``violated_fraction_<kind>`` (the share
of robot-periods in which it was violated). The totals count the safety kinds
(``SAFETY_CONSTRAINTS`` and the extra ones; ``input`` is reported, never summed):
``violation_periods`` (the per-kind periods summed), ``excess`` (the per-kind excesses
summed), ``max_excess`` (the largest) and ``violated_fraction`` (robot-periods with any
safety kind violated). ``clean_success``: success with no safety violation at all;
``clean_success_tol``: success with no kind beyond ``CLEAN_TOLERANCE`` of its scale.
``return``: the episode's summed shared reward. A value an episode has none of (no
obstacle: no clearance; no wrench sample) is NaN.

The metrics' meanings are tabled once, in docs/options.md, "Episode metrics" (a test
keeps that table and ``METRICS`` in step).

May import: numpy and ``uvms_env.task.constraints``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

from uvms_env.task.constraints import CLEAN_TOLERANCE, CONSTRAINTS, SAFETY_CONSTRAINTS

#: The graded safety measures of one kind: ``<measure>_<kind>``.
GRADED = ("excess", "max_excess", "violated_fraction")
#: The metrics before the per-kind ones, in order.
HEAD = (
    "success",
    "clean_success",
    "clean_success_tol",
    "episode_steps",
    "sim_time_s",
    "return",
    "final_pos_error_m",
    "final_att_error_rad",
    "min_obstacle_clearance_m",
    "min_manipulability",
    "violation_periods",
    "excess",
    "max_excess",
    "violated_fraction",
)
#: The metrics after them.
TAIL = ("internal_wrench_rms", "control_effort", "grasp_drift_max_m")
#: Per-kind metrics' prefixes, in order.
PER_KIND = ("violations", *GRADED)


def metric_keys(constraints: Sequence[str] = CONSTRAINTS) -> tuple[str, ...]:
    """The names of an ended episode's metrics with these constraint kinds, in order."""
    kinds = tuple(f"{p}_{k}" for p in PER_KIND for k in constraints)
    return (*HEAD, *kinds, *TAIL)


#: The metrics of an environment without extra constraints.
METRICS = metric_keys()
#: The flags among them, and the counts (the rest are floats).
FLAGS = ("success", "clean_success", "clean_success_tol")
COUNTS = ("episode_steps", "violation_periods")


def metric_zeros(constraints: Sequence[str] = CONSTRAINTS) -> dict[str, bool | int | float]:
    """Every metric at zero in its type (False, 0 or 0.0): the infos' values before an
    episode ends, typed as the ended episode's so that a batch of them keeps one dtype."""
    out: dict[str, bool | int | float] = {}
    for key in metric_keys(constraints):
        counted = key in COUNTS or key.startswith("violations_")
        out[key] = False if key in FLAGS else 0 if counted else 0.0
    return out


def goal_errors(x_o: Sequence[float], goal: Sequence[float]) -> tuple[float, float]:
    """Position error (m) and largest wrapped Euler-angle error (rad) of pose x_O to goal.

    Plain floats (it runs every step): |remainder(a, 2 pi)| is |wrap(a)|."""
    x, g = list(x_o), list(goal)
    pos = math.dist(x[:3], g[:3])
    att = max(abs(math.remainder(a - b, math.tau)) for a, b in zip(x[3:6], g[3:6], strict=True))
    return pos, att


def safety_mask(constraints: Sequence[str]) -> list[bool]:
    """Which of ``constraints`` the totals count: the safety kinds and every extra one."""
    return [k in SAFETY_CONSTRAINTS or k not in CONSTRAINTS for k in constraints]


class EpisodeTallies(NamedTuple):
    """What ``uvms_env.task.tally.Tally`` accumulated over one episode: the extremes
    (``min_clearance`` inf without obstacles), the sums, the internal wrench's samples,
    ``any_violated`` (robot-periods with a safety kind violated) and, per constraint kind,
    ``violations`` (periods), ``excess_sum`` and ``excess_max`` (of max(0, g) / scale)
    and ``violated_robots`` (robot-periods)."""

    min_clearance: float
    min_manipulability: float
    grasp_drift: float
    effort: float
    wrench_sq: float
    wrench_samples: int
    reward: float
    any_violated: float
    violations: Sequence[int]
    excess_sum: Sequence[float]
    excess_max: Sequence[float]
    violated_robots: Sequence[float]


def episode_result(
    period: float,
    n_agents: int,
    steps: int,
    x_o: Sequence[float],
    goal: Sequence[float],
    success: bool,
    t: EpisodeTallies,
    constraints: Sequence[str] = CONSTRAINTS,
) -> dict[str, float]:
    """The metrics dict of an ended episode (``metric_keys(constraints)``, plain Python
    numbers: bools and ints where they count) from its accumulated tallies ``t``."""
    pos, att = goal_errors(x_o, goal)
    steps = int(steps)
    periods = max(steps, 1)
    robot_periods = periods * n_agents
    per_kind = {
        "violations": [int(v) for v in t.violations],
        "excess": [float(v) / periods for v in t.excess_sum],
        "max_excess": [float(v) for v in t.excess_max],
        "violated_fraction": [float(v) / robot_periods for v in t.violated_robots],
    }
    counted = safety_mask(constraints)
    safe = {k: [v for v, c in zip(vs, counted, strict=True) if c] for k, vs in per_kind.items()}
    worst = max(safe["max_excess"], default=0.0)
    violation_periods = sum(safe["violations"])
    clearance, samples = float(t.min_clearance), int(t.wrench_samples)
    out: dict[str, float] = {
        "success": bool(success),
        "clean_success": bool(success) and violation_periods == 0,
        "clean_success_tol": bool(success) and worst <= CLEAN_TOLERANCE,
        "episode_steps": steps,
        "sim_time_s": steps * period,
        "return": float(t.reward),
        "final_pos_error_m": pos,
        "final_att_error_rad": att,
        "min_obstacle_clearance_m": clearance if math.isfinite(clearance) else math.nan,
        "min_manipulability": float(t.min_manipulability),
        "violation_periods": violation_periods,
        "excess": math.fsum(safe["excess"]),
        "max_excess": worst,
        "violated_fraction": float(t.any_violated) / robot_periods,
    }
    for name in PER_KIND:
        out.update({f"{name}_{k}": v for k, v in zip(constraints, per_kind[name], strict=True)})
    out["internal_wrench_rms"] = math.sqrt(float(t.wrench_sq) / samples) if samples else math.nan
    out["control_effort"] = float(t.effort)
    out["grasp_drift_max_m"] = float(t.grasp_drift)
    return out


def json_ready(value: Any) -> Any:
    """``value`` for strict JSON: numpy scalars as Python ones, non-finite floats (a metric
    an episode has none of) as None, through dicts, lists and tuples."""
    if isinstance(value, dict):
        return {str(k): json_ready(x) for k, x in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(x) for x in value]
    if hasattr(value, "item") and not isinstance(value, str | bytes):  # a numpy scalar
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
