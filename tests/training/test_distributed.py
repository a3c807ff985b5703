"""Scale-out: marl-eval JSON, the library switch, the Ray evaluation backend and RLlib
training evaluated through ``--policy rllib:PATH``.

The Ray tests need Ray (in the test extra; they skip where it is missing); the fast
RLlib run trains one iteration on the local runner and evaluates the checkpoint through
``rllib:PATH``; the 2-iteration, 2-runner run is ``slow``. BenchMARL's tasks are tested in
tests/training/test_benchmarl.py."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from baselines.evaluate import main as evaluate_main
from baselines.evaluation import marl_eval
from baselines.evaluation.outputs import write_outputs
from baselines.evaluation.runner import evaluate
from baselines.loaders.sources import PolicySource

TIMING = ("policy_time_ms_median", "policy_time_ms_p95", "policy_time_ms_max", "wall_s")


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(fh)]


def _number(text: str) -> float:
    if text in ("True", "False"):
        return float(text == "True")
    return float(text) if text else float("nan")


def test_marl_eval_json_has_marl_eval_structure_and_the_episode_values(tmp_path):
    out, path = tmp_path / "eval", tmp_path / "marl.json"
    common = ["--scenario", "short", "--episodes", "2", "--max-cycles", "8", "--workers", "1"]
    marl = ["--marl-eval-json", str(path), "--marl-eval-step-count", "1000"]
    evaluate_main(["--policy", "zero", "--policy", "random", *common, "--out", str(out), *marl])
    data = json.loads(path.read_text())
    assert list(data) == ["uvms"] and list(data["uvms"]) == ["short"]  # BenchMARL's names
    algos = data["uvms"]["short"]
    assert set(algos) == {"zero", "random"}
    rows = _csv_rows(out / "episodes.csv")
    for algo, runs in algos.items():
        assert list(runs) == ["seed_0"]
        run = runs["seed_0"]
        assert list(run) == ["step_0", "absolute_metrics"]
        step = run["step_0"]
        assert step["step_count"] == 1000 and isinstance(step["elapsed_time"], float)
        mine = [r for r in rows if r["policy"] == algo]
        # the short scenario has no obstacles: no clearance, so no such metric
        assert "min_obstacle_clearance_m" not in step
        assert {"return", "success", "final_pos_error_m", "episode_steps"} <= set(step)
        assert step["uvms_return"] == step["return"]  # BenchMARL's group return: the team's
        assert "violations_collision" in step  # and one list per constraint kind
        for metric in set(step) & set(marl_eval.METRICS) - {"uvms_return"}:
            expected = [_number(r[metric]) for r in mine]
            assert step[metric] == pytest.approx(expected, rel=1e-12)
            assert run["absolute_metrics"][metric] == step[metric]
    # a second evaluation of the same run is its next logging step; absolute stays last
    more = evaluate(["zero"], ["short"], 2, 0, 1, max_cycles=4, progress=False)
    marl_eval.write(path, more, 0, step_count=2000, elapsed_time=1.5)
    run = json.loads(path.read_text())["uvms"]["short"]["zero"]["seed_0"]
    assert list(run) == ["step_0", "step_1", "absolute_metrics"]
    assert run["step_1"]["step_count"] == 2000
    assert run["absolute_metrics"]["episode_steps"] == [4.0, 4.0]


def test_task_names_carry_the_team_size_and_algorithm_names_no_commas():
    assert marl_eval.task_name("random", {"n_agents": 3}) == "random_n3"
    assert marl_eval.task_name("random", {}) == "random_n2"  # BenchMARL's uvms/random_n2
    assert marl_eval.task_name("paper", {}) == "paper"
    assert marl_eval.algo_name("pkg.mod:f,x") == "pkg.mod:f;x"


def test_library_switch_reaches_rllib_without_importing_ray(capsys):
    from baselines.train import main as train_main

    with pytest.raises(SystemExit):
        train_main(["--library", "rllib", "--help"])
    assert "--num-env-runners" in capsys.readouterr().out


def test_rllib_policy_source_rejects_a_missing_checkpoint(tmp_path):
    source = PolicySource.parse(f"rllib:{tmp_path}")
    assert source.name == "rllib"
    with pytest.raises(ValueError, match="no RLlib checkpoint"):
        source.factory(0)


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_ray_backend_gives_the_process_pools_episodes_csv(local_ray, tmp_path):
    args = (["random"], ["short"], 4, 0, 2)
    pool = evaluate(*args, max_cycles=10, progress=False)
    cluster = evaluate(*args, max_cycles=10, progress=False, backend="ray")
    write_outputs(pool, 0, tmp_path / "pool")
    write_outputs(cluster, 0, tmp_path / "ray")
    assert _csv_rows(tmp_path / "ray" / "episodes.csv") == _csv_rows(
        tmp_path / "pool" / "episodes.csv"
    )
    assert len(cluster) == 4 and all(r["error"] == "" for r in cluster)


def _train_and_evaluate(tmp_path: Path, runners: int, iterations: int) -> list[dict]:
    from baselines.train import main as train_main

    run = tmp_path / "rllib_ppo"
    train_main(
        "--library rllib --algo ppo --scenario random --env-option n_agents=2"
        f" --num-env-runners {runners} --iterations {iterations} --robot-steps 100000"
        " --hp train_batch_size_per_learner=64 --hp minibatch_size=32 --hp num_epochs=1"
        " --env-option max_cycles=16 --geometry-pool 2 --num-envs 2 --checkpoint-every 128"
        f" --no-progress --out {run}".split()
    )
    config = json.loads((run / "config.json").read_text())
    own = config["library_settings"]
    assert own["iterations_done"] == iterations and own["num_env_runners"] == runners
    assert config["env_options"]["max_cycles"] == 16 and config["num_envs"] == 2
    progress = list(csv.DictReader(open(run / "progress.csv")))
    assert [int(r["iteration"]) for r in progress] == list(range(1, iterations + 1))
    # 64 env steps of 2 robots an iteration: a checkpoint every other iteration
    assert [int(r["robot_steps"]) for r in progress] == [128 * k for k in range(1, iterations + 1)]
    assert (run / "checkpoints" / f"robot_steps_{128 * iterations}").is_dir()
    rows = evaluate([f"rllib:{run}"], ["random"], 2, 0, 1, {"n_agents": 2}, 6, progress=False)
    assert all(r["error"] == "" and r["episode_steps"] == 6 for r in rows), rows
    again = evaluate([f"rllib:{run}"], ["random"], 2, 0, 1, {"n_agents": 2}, 6, progress=False)
    assert [r["return"] for r in again] == [r["return"] for r in rows]  # deterministic
    return rows


def test_rllib_sub_envs_cycle_through_their_own_geometries(local_ray):
    pytest.importorskip("ray.rllib")
    from ray.rllib.env.env_context import EnvContext

    from baselines.rl.rllib_env import make_env
    from uvms_env.vector.seeding import copy_reset_seed

    config = {"scenario": "short", "seed": 10, "geometry_pool": 7, "envs_per_runner": 2}
    config["num_env_runners"] = 2
    context = EnvContext({**config, "overrides": {"max_cycles": 3}}, worker_index=2)
    first, second = make_env(context), make_env(context)
    seeds = [[env._next_seed() for _ in range(3)] for env in (first, second)]
    # runner 2 of 2 holds copies 2 and 3 of K = 4: seed (10 + k + 4 e) mod 7, whatever
    # order RLlib resets in; the rule's function agrees with the written-out numbers
    assert {tuple(s) for s in seeds} == {(5, 2, 6), (6, 3, 0)}
    assert [copy_reset_seed(10, 2, e, 4, 7) for e in range(3)] == [5, 2, 6]


def test_rllib_ppo_smoke_on_the_local_runner_then_resumed_after_a_kill(local_ray, tmp_path):
    """One iteration, then the run as a kill after its numbered checkpoint leaves it (no
    final checkpoint, config.json as at the start): ``--resume RUN`` goes on from the
    checkpoint's robot-steps."""
    pytest.importorskip("ray.rllib")
    import shutil

    from baselines.train import main as train_main

    _train_and_evaluate(tmp_path, runners=0, iterations=1)
    run = tmp_path / "rllib_ppo"
    shutil.rmtree(run / "checkpoint")
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "robot_steps": 0}))
    train_main(f"--resume {run} --iterations 1 --no-progress".split())
    config = json.loads((run / "config.json").read_text())
    assert config["resumes"] == 1 and config["robot_steps"] == 256
    progress = list(csv.DictReader(open(run / "progress.csv")))
    assert [int(r["robot_steps"]) for r in progress] == [128, 256]


def _fake_checkpoint(folder: Path) -> Path:
    from baselines.loaders.rllib_policy import MODULE_DIR

    folder.joinpath(*MODULE_DIR).mkdir(parents=True)
    return folder


def test_rllib_resume_finds_the_newest_checkpoint_its_steps_and_multiplier(tmp_path):
    """``find_resume``: a killed run (numbered checkpoints, no final one) resumes from the
    newest numbered one, its robot-steps from the name and its multiplier from beside it;
    a final checkpoint newer than those from config.json's record; a checkpoint named
    directly as itself; a folder with none is refused by name."""
    import os

    from baselines.rl.rllib_trainer import find_resume

    run = tmp_path / "run"
    for steps in (128, 1024, 256):  # 1024 newest by steps, not by name order
        _fake_checkpoint(run / "checkpoints" / f"robot_steps_{steps}")
    (run / "checkpoints" / "robot_steps_1024.json").write_text('{"multiplier": 0.7}')
    recorded = {"robot_steps": 5000, "cost": {"final_multiplier": 2.5}}
    assert find_resume(run, recorded) == (run / "checkpoints" / "robot_steps_1024", 1024, 0.7)
    low = run / "checkpoints" / "robot_steps_256"
    assert find_resume(low, recorded) == (low, 256, None)  # no multiplier saved beside it
    final = _fake_checkpoint(run / "checkpoint")
    newest = (run / "checkpoints" / "robot_steps_1024").stat().st_mtime
    os.utime(final, (newest + 10, newest + 10))
    assert find_resume(run, recorded) == (final, 5000, 2.5)
    os.utime(final, (newest - 10, newest - 10))  # a kill after a later checkpoint
    assert find_resume(run, recorded)[1] == 1024
    with pytest.raises(ValueError, match="no RLlib checkpoint"):
        find_resume(tmp_path / "empty", {})


@pytest.mark.slow
def test_rllib_ppo_two_iterations_two_env_runners_then_rllib_policy(local_ray, tmp_path):
    pytest.importorskip("ray.rllib")
    _train_and_evaluate(tmp_path, runners=2, iterations=2)
    out = tmp_path / "eval"
    evaluate_main(
        f"--policy rllib:{tmp_path / 'rllib_ppo'} --scenario random --n-agents 2 --episodes 2"
        f" --max-cycles 6 --workers 2 --backend ray --out {out}".split()
    )
    assert len(_csv_rows(out / "episodes.csv")) == 2
