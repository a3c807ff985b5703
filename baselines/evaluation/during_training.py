"""A training run's periodic evaluations: the saved policy on each rung through the
evaluator, one row per rung in the run's evaluations.csv and its episodes in the run's
marl-eval JSON, and how one evaluation ranks against another (the best snapshot). Every
training loop that evaluates as it learns (the RL trainers, DAgger) calls it.

May import: the standard library, numpy and this package.
"""

from __future__ import annotations

import csv
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

EVAL_FILE = "evaluations.csv"
# One row per evaluation and rung (deterministic policy, fixed seeds).
EVAL_COLUMNS = (
    "robot_steps",
    "rung",
    "success_rate",
    "clean_success_rate",
    "violation_periods",
    "violation_periods_median",
    "mean_return",
    "final_pos_error_m",
    "episode_steps",
    "errors",
)


def evaluate_rungs(
    folder: Path,
    rungs: dict[str, tuple[str, dict[str, Any]]],
    policy: str,
    episodes: int,
    seed: int,
    robot_steps: int,
    algorithm: str,
    training_seed: int,
    elapsed: float = 0.0,
    max_cycles: int | None = None,
) -> list[dict[str, Any]]:
    """``policy`` (an evaluator ``--policy`` spec) on every rung, ``episodes`` each from
    ``seed`` (capped at ``max_cycles`` periods, None: the scenarios' own episodes): one row
    per rung appended to ``folder``'s evaluations.csv (``EVAL_COLUMNS``)
    and the episodes to its marl_eval.json (as run ``seed_TRAINING_SEED`` of ``algorithm``,
    so that every snapshot of a run is one marl-eval run); returns the rows. Every
    training loop that evaluates as it learns (the RL trainers, DAgger) writes here."""
    from baselines.evaluation import marl_eval
    from baselines.evaluation.runner import evaluate
    from baselines.evaluation.summary import aggregate

    out = []
    for rung, (scenario, overrides) in rungs.items():
        rows = evaluate(
            [policy],
            [scenario],
            episodes,
            seed,
            1,
            overrides,
            max_cycles,
            progress=False,
            check=False,  # a training run goes on: failed episodes are warned of below
            batch=episodes,  # the rung's episodes on one batched env (the same episodes)
        )
        summary = aggregate(rows, seed)[0]
        failed = [r["error"] for r in rows if r["error"]]
        if failed:
            warnings.warn(
                f"evaluation on {rung}: {len(failed)} episodes failed: {failed[0]}",
                stacklevel=2,
            )
        row = {
            "robot_steps": int(robot_steps),
            "rung": rung,
            "success_rate": summary["success_rate"],
            "clean_success_rate": summary["clean_success_rate"],
            "violation_periods": float(np.mean([r["violation_periods"] for r in rows])),
            "violation_periods_median": float(np.median([r["violation_periods"] for r in rows])),
            "mean_return": summary.get("return", math.nan),
            "final_pos_error_m": summary.get("final_pos_error_m", math.nan),
            "episode_steps": summary.get("episode_steps", math.nan),
            "errors": summary["errors"],
        }
        append_row(Path(folder) / EVAL_FILE, EVAL_COLUMNS, row)
        marl_eval.write(
            Path(folder) / "marl_eval.json",
            rows,
            seed,
            identity=marl_eval.RunIdentity(algorithm, training_seed),
            step_count=int(robot_steps),
            elapsed_time=elapsed,
            overrides=overrides,
        )
        out.append(row)
    return out


def append_row(path: Path, columns: tuple[str, ...], row: dict[str, Any]) -> None:
    """Append ``row`` to the CSV file ``path`` of ``columns``, the header first where
    there is no file yet (a training run's records: evaluations, progress, the shield's)."""
    new = not path.exists()
    with open(path, "a", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        if new:
            writer.writeheader()
        writer.writerow(row)


def evaluation_score(rows: list[dict[str, Any]]) -> tuple[float, float, float]:
    """How one evaluation (its rows, one per rung) ranks against another, higher better:
    clean successes summed over the rungs, then successes, then the fewest violation
    periods (the rungs' medians summed, negated)."""
    return (
        round(sum(r["clean_success_rate"] for r in rows), 9),
        round(sum(r["success_rate"] for r in rows), 9),
        -round(sum(r["violation_periods_median"] for r in rows), 9),
    )
