"""Learning-curve figures over seeds (``baselines.rl.plot``) from run folders."""

from __future__ import annotations

import csv
import json

import numpy as np

from baselines.rl import plot


def _run(folder, seed: int, rung: str) -> None:
    folder.mkdir()
    (folder / "config.json").write_text(
        json.dumps({"algo": "ppo", "scenario": "random", "overrides": {}, "seed": seed})
    )
    steps = np.arange(1, 6) * 1000
    with open(folder / "progress.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["robot_steps", "episode_return_mean", "episode_cost_mean"])
        w.writerows([[t, -t / 100 + seed, 50 - t / 200] for t in steps])
    with open(folder / "evaluations.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["robot_steps", "rung", "success_rate", "clean_success_rate"])
        w.writerows([[t, rung, 0.25 * (seed + 1), 0.0] for t in steps[1::2]])


def test_group_curves_from_runs_evaluated_without_the_ladder(tmp_path):
    """A run trained without --eval-ladder labels its evaluations with the scenario's
    name; a group name may hold "=" (split at the last one)."""
    runs = [tmp_path / f"s{k}" for k in range(3)]
    for k, run in enumerate(runs):
        _run(run, k, "random")
    evals = plot._rung_evaluations(runs[1])
    assert evals is not None
    np.testing.assert_array_equal(evals["robot_steps"], [2000, 4000])
    np.testing.assert_array_equal(evals["success_rate"], [0.5, 0.5])
    out = tmp_path / "fig.png"
    plot.main(["--group", f"PPO, N = 2={','.join(map(str, runs))}", "--out", str(out)])
    assert out.stat().st_size > 10_000


def test_ladder_rows_are_preferred_and_other_rungs_ignored(tmp_path):
    run = tmp_path / "ladder"
    _run(run, 0, "random_n2")
    with open(run / "evaluations.csv", "a", newline="") as fh:
        csv.writer(fh).writerow([2000, "paper", 1.0, 1.0])
    evals = plot._rung_evaluations(run)
    assert evals is not None and list(evals["success_rate"]) == [0.25, 0.25]
