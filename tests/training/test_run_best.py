"""The run layer keeps the best-evaluated snapshot (early stopping on the evaluation seed)."""

from __future__ import annotations

import json

from baselines.evaluation.during_training import evaluation_score
from baselines.runs import BEST, Run, RunSettings


def _rows(clean: float, success: float, violations: float) -> list[dict]:
    return [
        {"clean_success_rate": clean, "success_rate": success, "violation_periods_median": v}
        for v in (violations, violations)
    ]


def test_the_score_ranks_clean_successes_then_successes_then_fewer_violations():
    assert evaluation_score(_rows(0.5, 0.5, 900)) > evaluation_score(_rows(0.0, 1.0, 0))
    assert evaluation_score(_rows(0.5, 1.0, 900)) > evaluation_score(_rows(0.5, 0.5, 0))
    assert evaluation_score(_rows(0.5, 1.0, 3)) > evaluation_score(_rows(0.5, 1.0, 4))


def _run(tmp_path, resume=None) -> Run:
    settings = RunSettings("short", out=tmp_path / "run", progress=False, resume=resume)
    previous = json.loads((tmp_path / "run" / "config.json").read_text()) if resume else None
    return Run(settings, "sb3", "ppo", ["train"], previous)


def _snapshot(run: Run, tag: str) -> None:
    run.snapshot.mkdir(exist_ok=True)
    (run.snapshot / "model.zip").write_text(tag)


def test_best_holds_the_best_snapshot_and_survives_a_resume(tmp_path):
    run = _run(tmp_path)
    run.write_config()
    _snapshot(run, "first")
    assert run.keep_best(100, _rows(0.5, 1.0, 10))
    _snapshot(run, "worse")
    assert not run.keep_best(200, _rows(0.0, 1.0, 0))
    assert (run.folder / BEST / "model.zip").read_text() == "first"
    resumed = _run(tmp_path, resume=tmp_path / "run")
    _snapshot(resumed, "tie")
    assert not resumed.keep_best(300, _rows(0.5, 1.0, 10))  # a tie keeps the earlier one
    _snapshot(resumed, "better")
    assert resumed.keep_best(400, _rows(1.0, 1.0, 0))
    assert (resumed.folder / BEST / "model.zip").read_text() == "better"
    config = json.loads((resumed.folder / "config.json").read_text())
    assert config["best"]["robot_steps"] == 400
    assert json.loads((resumed.folder / BEST / "config.json").read_text())["best"] == config["best"]
