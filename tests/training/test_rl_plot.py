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


def test_a_distribution_run_is_drawn_over_every_rung_and_without_a_cost(tmp_path):
    """A run over several team sizes evaluated on the ladder: its curve is the mean over
    the rungs at each evaluation; a progress.csv whose cost column is empty (no --cost)
    draws no cost curve rather than failing."""
    runs = []
    for k in range(2):
        run = tmp_path / f"d{k}"
        _run(run, k, "random_n2")
        config = json.loads((run / "config.json").read_text())
        config.update(eval_ladder=True, team_sizes=[2, 3])
        (run / "config.json").write_text(json.dumps(config))
        with open(run / "evaluations.csv", "a", newline="") as fh:
            csv.writer(fh).writerows([[2000, "random_n3", 0.75, 0.5], [4000, "paper", 0.0, 0.0]])
        with open(run / "progress.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["robot_steps", "episode_return_mean", "episode_cost_mean"])
            w.writerows([[t, -t / 100, ""] for t in (1000, 2000, 3000)])
        runs.append(run)
    evals = plot._rung_evaluations(runs[0])
    assert evals is not None
    np.testing.assert_array_equal(evals["robot_steps"], [2000, 4000])
    np.testing.assert_allclose(evals["success_rate"], [(0.25 + 0.75) / 2, (0.25 + 0.0) / 2])
    np.testing.assert_allclose(evals["clean_success_rate"], [0.25, 0.0])
    out = tmp_path / "fig.png"
    plot.main(["--group", f"IPPO={','.join(map(str, runs))}", "--out", str(out)])
    assert out.stat().st_size > 10_000
