"""The evaluator's marl-eval JSON merges with BenchMARL's: one environment and task names,
each policy's run named by its training (algorithm, seed), the untrained policies filed
under the trained ones' seeds, and ``merge`` giving a dataset that marl-eval's own pipeline
(``data_process_pipeline``, ``create_matrices_for_rliable``) reads; that last part skips
without ``id-marl-eval`` (``pip install id-marl-eval``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from baselines.evaluation import marl_eval

KINDS = ("collision", "workspace")
# id-marl-eval 0.0.4 pins pandas 1.4.4 (no Python 3.11 wheel); the pipeline needs numpy only
MARL_EVAL = "pip install --no-deps id-marl-eval colorama"


def _row(policy: str, episode: int, ret: float, success: bool) -> dict[str, Any]:
    """An evaluator row (``baselines.evaluation``) with the columns marl_eval reads."""
    return {
        "policy": policy,
        "scenario": "random",
        "episode": episode,
        "return": ret,
        "success": success,
        "clean_success": success,
        "episode_steps": 100 + episode,
        "final_pos_error_m": 0.1,
        "final_att_error_rad": 0.01,
        "min_obstacle_clearance_m": 1.5,
        "violation_periods": 3,
        "internal_wrench_rms": 2.0,
        **{f"violations_{k}": 0 for k in KINDS},
    }


def _run(folder: Path, seed: int, library: str | None = "sb3") -> str:
    """A training run folder as the project's trainers leave it: config.json, model.zip."""
    folder.mkdir()
    config = {"library": library, "algo": "ppo", "seed": seed}
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "model.zip").write_bytes(b"")
    return f"ppo:{folder}"


def _benchmarl_json(algo: str, seeds: tuple[int, ...]) -> dict[str, Any]:
    """A BenchMARL 1.5.2 experiment's JSON (its ``JsonWriter``) for ``uvms/random_n2``, with
    ``baselines.benchmarl_tasks.episode_logs.EpisodeMetrics``: absolute_metrics first (each
    the maximum), then one step per evaluation, ``step_<total_frames // evaluation_interval>``."""
    runs = {}
    for seed in seeds:
        step = {
            "step_count": 6000,
            "uvms_return": [-60.0, -50.0],
            "return": [-60.0, -50.0],
            "success": [0.0, 1.0],
            "clean_success": [0.0, 0.0],
            "violation_periods": [12.0, 4.0],
            "episode_steps": [3000.0, 900.0],
            "final_pos_error_m": [2.0, 0.1],
            "final_att_error_rad": [0.5, 0.05],
            **{f"violations_{k}": [0.0, 0.0] for k in KINDS},
            "episode_cost": [30.0, 8.0],  # per robot: the evaluator has no such column
        }
        absolute = {k: [max(v)] for k, v in step.items() if k != "step_count"}
        runs[f"seed_{seed}"] = {"absolute_metrics": absolute, "step_0": step}
    return {"uvms": {"random_n2": {algo: runs}}}


def test_a_saved_policy_is_filed_under_the_algorithm_and_seed_that_trained_it(tmp_path):
    trained = _run(tmp_path / "ppo_s7", 7)
    old = _run(tmp_path / "old", 3, library=None)  # a record from before the library key
    assert marl_eval.run_identity(trained) == marl_eval.RunIdentity("sb3_ppo", 7)
    assert marl_eval.run_identity(old) == marl_eval.RunIdentity("sb3_ppo", 3)
    assert marl_eval.run_identity(f"{trained}+filter").algorithm == "sb3_ppo+filter"
    # no run record, nothing saved, or not a saved network: the label, no seed
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "model.zip").write_bytes(b"")
    for label in (f"ppo:{bare}", f"ppo:{tmp_path / 'missing'}", "nmpc", "zero"):
        assert marl_eval.run_identity(label) == marl_eval.RunIdentity(label, None)


def test_untrained_policies_share_the_trained_policies_runs(tmp_path):
    seven, eight = _run(tmp_path / "s7", 7), _run(tmp_path / "s8", 8)
    rows = [_row(p, e, -40.0 - e, e == 0) for p in (seven, eight, "nmpc") for e in range(2)]
    data = marl_eval.add_evaluation({}, rows, seed=202)
    algos = data["uvms"]["random_n2"]
    assert set(algos) == {"sb3_ppo", "nmpc"}  # two runs of one algorithm: one algorithm
    assert set(algos["sb3_ppo"]) == set(algos["nmpc"]) == {"seed_7", "seed_8"}
    nmpc = algos["nmpc"]
    assert nmpc["seed_7"] == nmpc["seed_8"]  # the same episodes under each training seed
    assert list(nmpc["seed_7"]) == ["step_0", "absolute_metrics"]
    assert nmpc["seed_7"]["step_0"]["success"] == [1.0, 0.0]
    # a later evaluation of the expert alone joins the runs the file holds for the task
    marl_eval.add_evaluation(data, [_row("nmpc", 0, -1.0, True)], seed=5, step=1)
    assert set(data["uvms"]["random_n2"]["nmpc"]) == {"seed_7", "seed_8"}
    # with no trained policy anywhere: the evaluation seed, as before
    alone = marl_eval.add_evaluation({}, [_row("nmpc", 0, -1.0, True)], seed=5)
    assert set(alone["uvms"]["random_n2"]["nmpc"]) == {"seed_5"}


def _ours_and_benchmarls(tmp_path: Path) -> dict[str, Any]:
    seven, eight = _run(tmp_path / "s7", 7), _run(tmp_path / "s8", 8)
    rows = [_row(p, e, -40.0 - e, e == 0) for p in (seven, eight, "nmpc") for e in range(2)]
    ours = marl_eval.add_evaluation({}, rows, seed=202, step_count=6000)
    return marl_eval.merge(_benchmarl_json("mappo", (7, 8)), ours)


def test_merge_keeps_every_run_and_the_metrics_all_of_them_hold(tmp_path):
    merged = _ours_and_benchmarls(tmp_path)
    assert list(merged) == ["uvms"] and list(merged["uvms"]) == ["random_n2"]
    algos = merged["uvms"]["random_n2"]
    assert set(algos) == {"mappo", "sb3_ppo", "nmpc"}
    assert all(set(runs) == {"seed_7", "seed_8"} for runs in algos.values())
    entries = [e for runs in algos.values() for run in runs.values() for e in run.values()]
    metrics = {m for m in entries[0] if marl_eval.is_metric(m)}
    assert all({m for m in e if marl_eval.is_metric(m)} == metrics for e in entries)
    assert {"return", "uvms_return", "success", "clean_success", "violation_periods"} <= metrics
    assert "violations_collision" in metrics
    # only one side has them: BenchMARL's per-robot cost, the evaluator's clearance
    assert not {"episode_cost", "min_obstacle_clearance_m", "internal_wrench_rms"} & metrics
    # the same logging step given twice, differently, is an error
    other = _benchmarl_json("mappo", (7,))
    other["uvms"]["random_n2"]["mappo"]["seed_7"]["step_0"]["return"] = [0.0, 0.0]
    with pytest.raises(ValueError, match="mappo/seed_7/step_0"):
        marl_eval.merge(merged, other)


def test_final_merge_compares_each_runs_last_evaluation(tmp_path):
    curve = _benchmarl_json("mappo", (7,))
    run = curve["uvms"]["random_n2"]["mappo"]["seed_7"]
    run["step_3"] = {**run["step_0"], "step_count": 24000, "return": [-5.0, -7.0]}
    ours = marl_eval.add_evaluation({}, [_row("nmpc", 0, -1.0, True)], seed=7)
    merged = marl_eval.merge(curve, ours, final=True)["uvms"]["random_n2"]
    mappo = merged["mappo"]["seed_7"]
    assert list(mappo) == ["step_0", "absolute_metrics"] and list(merged["nmpc"]) == ["seed_7"]
    assert mappo["step_0"]["step_count"] == 24000
    assert mappo["absolute_metrics"]["return"] == [-5.0, -7.0]  # the episodes, not a maximum


def test_merge_command_writes_the_merged_file(tmp_path):
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "out" / "c.json"
    a.write_text(json.dumps(_benchmarl_json("mappo", (7,))))
    b.write_text(json.dumps(_benchmarl_json("masac", (7,))))
    marl_eval.main(["merge", str(a), str(b), "--out", str(out)])
    assert set(json.loads(out.read_text())["uvms"]["random_n2"]) == {"mappo", "masac"}


def test_marl_evals_pipeline_reads_the_merged_files(tmp_path):
    utils = pytest.importorskip("marl_eval.utils.data_processing_utils", reason=MARL_EVAL)
    merged = _ours_and_benchmarls(tmp_path)
    processed = utils.data_process_pipeline(raw_data=merged, metrics_to_normalize=["return"])
    # the pipeline prints and returns its input on a format error: it must have processed
    assert "extra" in processed, "marl-eval rejected the merged data"
    assert sorted(processed["extra"]["algorithm_list"]) == ["mappo", "nmpc", "sb3_ppo"]
    assert processed["extra"]["number_of_runs"] == 2
    final, per_step = utils.create_matrices_for_rliable(
        data_dictionary=processed, environment_name="uvms", metrics_to_normalize=["return"]
    )
    # one (runs x tasks) table per metric and algorithm, the runs in the same order
    assert final["mean_success"]["nmpc"].shape == (2, 1)
    assert final["mean_success"]["nmpc"][:, 0].tolist() == [0.5, 0.5]
    assert final["mean_success"]["mappo"][:, 0].tolist() == [1.0, 1.0]  # its maximum
    assert per_step["mean_norm_return"]["sb3_ppo"].shape == (2, 1, 1)  # runs, tasks, steps


def test_the_old_names_are_what_marl_eval_could_not_read(tmp_path):
    """The issue's failure, kept as a check of the test's own fixture: an evaluation seed
    for a run and the policy label for an algorithm leave the runs unaligned."""
    utils = pytest.importorskip("marl_eval.utils.data_processing_utils", reason=MARL_EVAL)
    ours = {"uvms": {"random_n2": {"nmpc": {"seed_1": {"step_0": {"step_count": 0}}}}}}
    ours["uvms"]["random_n2"]["nmpc"]["seed_1"]["step_0"]["return"] = [1.0]
    ours["uvms"]["random_n2"]["nmpc"]["seed_1"]["absolute_metrics"] = {"return": [1.0]}
    raw = {
        "uvms": {
            "random_n2": {
                **ours["uvms"]["random_n2"],
                **_benchmarl_json("mappo", (0,))["uvms"]["random_n2"],
            }
        }
    }
    processed = utils.data_process_pipeline(raw_data=raw, metrics_to_normalize=["return"])
    with pytest.raises(KeyError, match="seed_"):
        utils.get_and_aggregate_data_single_task(
            processed, "return", ["return"], "random_n2", "uvms"
        )
