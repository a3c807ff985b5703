"""One training layer under three libraries (``baselines.train --library {sb3,benchmarl,rllib}``):
each trains for a tiny budget and writes the same progress.csv and evaluations.csv
columns and the same config.json keys; every library's ``--help`` lists the same shared
options; the learning-curve figure draws runs of all three; every PPO trainer takes
PPO-Lagrangian's dual step the same way (and RLlib's env runners apply each new
multiplier)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from baselines import runs
from baselines.evaluation.during_training import EVAL_COLUMNS
from baselines.registry import LIBRARIES
from baselines.train import SHARED_GROUP, build_parser, main

# Tiny: one or two iterations of a few dozen robot-steps, small networks, 2 env copies of
# 2 robots, 6-step episodes; one evaluation episode (its length: the plain scenario's).
# The keys every library's config.json has, in order (the trainer adds ``library_settings``).
CONFIG_KEYS = (
    "library",
    "algo",
    "command",
    "scenario",
    "overrides",
    "env_defaults",
    "env_options",
    "num_envs",
    "seed",
    "robot_steps_budget",
    "eval_every",
    "eval_episodes",
    "eval_ladder",
    "eval_seed",
    "eval_max_cycles",
    "team_sizes",
    "objects",
    "checkpoint_every",
    "cost",
    "resumes",
    "hardware",
    "library_settings",
    "robot_steps",
    "wall_time_s",
    "build_s",
    "train_s",
    "eval_s",
    "robot_steps_per_s",
    "eval",
    "best",
)

TINY = [
    *("--scenario", "short", "--num-envs", "2", "--seed", "1", "--no-progress"),
    *("--env-option", "max_cycles=6", "--checkpoint-every", "0"),
]
COMMON = [*TINY, "--eval-every", "64", "--eval-episodes", "1", "--eval-max-cycles", "30"]
LIBRARY_ARGS = {
    "sb3": [
        "--hp",
        "n_steps=16",
        "--hp",
        "batch_size=32",
        "--hp",
        "n_epochs=1",
        "--hp",
        'policy_kwargs={"net_arch": [8]}',
    ],
    # 2 copies x 16 steps x 2 robots: 64 robot-steps an iteration
    "benchmarl": [
        "--hp",
        "experiment.on_policy_collected_frames_per_batch=32",
        "--hp",
        "experiment.on_policy_minibatch_size=16",
        "--hp",
        "experiment.on_policy_n_minibatch_iters=1",
        "--hp",
        "model.num_cells=[8]",
        "--hp",
        "critic_model.num_cells=[8]",
        "--geometry-pool",
        "0",
    ],
    "rllib": [
        "--num-env-runners",
        "0",
        "--geometry-pool",
        "2",
        "--hp",
        "train_batch_size_per_learner=32",
        "--hp",
        "minibatch_size=16",
        "--hp",
        "num_epochs=1",
    ],
}


def _header(path: Path) -> list[str]:
    with open(path, newline="") as fh:
        return next(csv.reader(fh))


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray for this module's RLlib runs, shut down after them (the RLlib trainer leaves
    the one it starts running, which another module's ``ray.init`` would meet)."""
    ray = pytest.importorskip("ray")
    pytest.importorskip("ray.rllib")
    started = not ray.is_initialized()
    if started:
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    if started:
        ray.shutdown()


@pytest.fixture(scope="module")
def trained(tmp_path_factory, request) -> dict[str, Path]:
    """A run folder per available library, 64 robot-steps each."""
    folders: dict[str, Path] = {}
    base = tmp_path_factory.mktemp("libraries")
    for library in LIBRARIES:
        if library == "rllib":
            request.getfixturevalue("local_ray")
        out = base / library
        main(
            [
                "--library",
                library,
                "--robot-steps",
                "64",
                "--out",
                str(out),
                *COMMON,
                *LIBRARY_ARGS[library],
            ]
        )
        folders[library] = out
    return folders


def test_every_library_writes_the_same_records(trained):
    assert set(trained) == set(LIBRARIES)
    for library, run in trained.items():
        assert _header(run / "progress.csv") == list(runs.PROGRESS_COLUMNS), library
        assert _header(run / "evaluations.csv") == list(EVAL_COLUMNS), library
        config = json.loads((run / "config.json").read_text())
        assert list(config) == list(CONFIG_KEYS), library
        # PPO, shared by the robots: MAPPO for BenchMARL (its algorithms are multi-agent)
        assert config["library"] == library and config["algo"] == LIBRARIES[library].algos[0]
        assert config["command"].startswith(f"python -m baselines.train --library {library}")
        assert config["num_envs"] == 2 and config["seed"] == 1
        assert config["overrides"] == {"max_cycles": 6}
        assert config["robot_steps"] >= 64 and config["wall_time_s"] > 0
        # the build, the training and the evaluations timed apart, within the wall time
        parts = [config[k] for k in ("build_s", "train_s", "eval_s")]
        assert all(p >= 0 for p in parts) and sum(parts) <= config["wall_time_s"] + 0.2
        progress = _rows(run / "progress.csv")
        steps = [int(r["robot_steps"]) for r in progress]
        assert steps == sorted(steps) and steps[-1] == config["robot_steps"], library
        # each 6-step team episode of each copy ends inside the budget
        ended = sum(int(r["episodes"]) for r in progress)
        assert ended >= 2 * (config["robot_steps"] // (2 * 2 * 6)) - 2, (library, ended)
        lengths = {float(r["episode_len_mean"]) for r in progress if r["episode_len_mean"]}
        assert lengths == {6.0}, library
        evaluations = _rows(run / "evaluations.csv")
        assert [r["rung"] for r in evaluations] == ["short"] and evaluations[0]["errors"] == "0"
        assert int(evaluations[0]["robot_steps"]) == 64
        assert len(config["eval"]["episodes"]) == runs.RECORD_EPISODES


def test_the_plot_draws_the_three_libraries_runs(trained, tmp_path):
    from baselines.rl import plot

    out = tmp_path / "curves.png"
    plot.main([*map(str, trained.values()), "--out", str(out)])
    assert out.stat().st_size > 10_000
    labels = [plot.label(run) for run in trained.values()]
    assert [label.split()[0] for label in labels] == list(trained)


@pytest.mark.parametrize("library", ["sb3", "benchmarl"])
def test_a_resumed_run_goes_on_where_it_stopped_and_appends_to_its_records(
    library, trained, tmp_path
):
    import shutil

    run = tmp_path / library
    shutil.copytree(trained[library], run)
    before = json.loads((run / "config.json").read_text())
    main(
        [
            "--library",
            library,
            "--robot-steps",
            "128",
            "--out",
            str(run),
            "--resume",
            str(run),
            *TINY,
            *LIBRARY_ARGS[library],
        ]
    )
    config = json.loads((run / "config.json").read_text())
    assert config["resumes"] == 1 and config["robot_steps"] == 128
    assert config["wall_time_s"] > before["wall_time_s"]  # both sessions
    progress = _rows(run / "progress.csv")
    assert [int(r["iteration"]) for r in progress] == [1, 2]
    assert [int(r["robot_steps"]) for r in progress] == [64, 128]


def _shared_options(library: str) -> list[list[str]]:
    ap = build_parser(library)
    (group,) = [g for g in ap._action_groups if g.title == SHARED_GROUP]
    return [a.option_strings for a in group._group_actions if a.help != "==SUPPRESS=="]


def test_every_library_lists_the_same_shared_options(capsys):
    listed = {library: _shared_options(library) for library in LIBRARIES}
    assert listed["sb3"] == listed["benchmarl"] == listed["rllib"]
    flags = [f for options in listed["sb3"] for f in options]
    for name in ("--robot-steps", "--num-envs", "--env-option", "--eval-every", "--resume"):
        assert name in flags
    for library in LIBRARIES:
        with pytest.raises(SystemExit):
            main(["--library", library, "--help"])
        text = capsys.readouterr().out
        shared = text[text.index(SHARED_GROUP) :].split(f"{library} library:")[0]
        assert all(f in shared for f in flags), library


def test_the_earlier_engine_flag_still_picks_the_library(capsys):
    assert build_parser("rllib").parse_args(["--engine", "rllib"]).library == "rllib"
    with pytest.raises(SystemExit):
        main(["--engine", "rllib", "--help"])
    text = capsys.readouterr().out
    assert "rllib library:" in text and "--engine {" not in text  # accepted, not listed


def _cost_run(library: str, out: Path, robot_steps: int, cost: list[str], *extra: str) -> None:
    main(
        [
            "--library",
            library,
            "--robot-steps",
            str(robot_steps),
            "--out",
            str(out),
            *COMMON[:-4],
            *cost,
            *LIBRARY_ARGS[library],
            *extra,
        ]
    )


def _check_dual_steps(rows: list[dict[str, str]], start: float, lr: float, limit: float) -> float:
    """Each row's multiplier is the previous one moved by lr (its episode cost - limit),
    clipped at 0; returns the last."""
    multiplier = start
    for row in rows:
        mean = float(row["episode_cost_mean"])  # 6-step episodes end in every rollout
        assert mean > 0.0  # exploration violates the speed limits
        multiplier = max(0.0, multiplier + lr * (mean - limit))
        assert float(row["multiplier"]) == pytest.approx(multiplier, rel=1e-5)
    return multiplier


DUAL = ["--cost", "magnitude", "--cost-weight", "0.5", "--multiplier-lr", "0.1"]
DUAL += ["--cost-limit", "0.2"]


@pytest.mark.parametrize("library", ["sb3", "benchmarl", "rllib"])
def test_ppo_lagrangian_takes_the_dual_step_from_each_rollouts_episode_cost(
    library, tmp_path, monkeypatch, request
):
    """Every PPO trainer: after each rollout the multiplier moves by lr (mean episode cost -
    limit), clipped at 0, from 0.5; config.json keeps the last. RLlib's env runners hold
    each new multiplier before the next iteration samples."""
    held: list[list[float]] = []
    if library == "rllib":
        request.getfixturevalue("local_ray")
        from baselines.rl import rllib_trainer as rllib_train
        from baselines.rl.rllib_env import runner_envs

        step = rllib_train.Trainer.dual_step

        def recording(self):
            stats = step(self)
            held.extend(
                self.algorithm.env_runner_group.foreach_env_runner(
                    lambda r: [e.lagrangian.multiplier for e in runner_envs(r)]
                )
            )
            return stats

        monkeypatch.setattr(rllib_train.Trainer, "dual_step", recording)
    out = tmp_path / library
    _cost_run(library, out, 192, DUAL)
    rows = _rows(out / "progress.csv")
    assert len(rows) == 3
    multiplier = _check_dual_steps(rows, 0.5, 0.1, 0.2)
    config = json.loads((out / "config.json").read_text())
    assert config["cost"]["final_multiplier"] == pytest.approx(multiplier, rel=1e-5)
    if library == "rllib":
        # the local runner's 2 env copies, each with the row's multiplier
        assert held == [pytest.approx([float(r["multiplier"])] * 2, rel=1e-5) for r in rows]


def test_sb3_resumes_a_killed_run_with_the_multiplier_saved_at_its_checkpoint(tmp_path):
    """Each checkpoint keeps the multiplier in force while it was saved (the one the row
    before it set); a session killed after a checkpoint writes no final multiplier, and its
    resume from that checkpoint goes on from the saved one, not from --cost's start."""
    out = tmp_path / "sb3"
    _cost_run("sb3", out, 192, DUAL, "--checkpoint-every", "64")
    rows = _rows(out / "progress.csv")
    checkpoints = out / "checkpoints"
    saved = {
        int(p.stem.split("_")[-2]): json.loads(p.read_text())["multiplier"]
        for p in checkpoints.glob("rl_model_multiplier_*_steps.json")
    }
    expected = [0.5, float(rows[0]["multiplier"]), float(rows[1]["multiplier"])]
    assert [saved[s] for s in (64, 128, 192)] == pytest.approx(expected, rel=1e-5)
    assert expected[1] != 0.5
    # killed between the checkpoints at 128 and 192: no final model, no final multiplier
    for name in ("model.zip", "vecnormalize.pkl", *(p.name for p in checkpoints.glob("*_192_*"))):
        (checkpoints / name if "192" in name else out / name).unlink()
    config = json.loads((out / "config.json").read_text())
    del config["cost"]["final_multiplier"]
    (out / "config.json").write_text(json.dumps(config))
    _cost_run("sb3", out, 192, DUAL, "--checkpoint-every", "64", "--resume", str(out))
    config = json.loads((out / "config.json").read_text())
    assert config["resumes"] == 1 and config["cost"]["multiplier"] == pytest.approx(expected[1])
    resumed = _rows(out / "progress.csv")[3:]
    assert [int(r["robot_steps"]) for r in resumed] == [192]
    last = _check_dual_steps(resumed, expected[1], 0.1, 0.2)
    assert config["cost"]["final_multiplier"] == pytest.approx(last, rel=1e-5)


def test_rllib_resumes_with_the_last_multiplier(local_ray, tmp_path):
    out = tmp_path / "rllib"
    _cost_run("rllib", out, 64, DUAL)
    first = json.loads((out / "config.json").read_text())["cost"]["final_multiplier"]
    assert first != 0.5
    _cost_run("rllib", out, 128, DUAL, "--resume", str(out))
    config = json.loads((out / "config.json").read_text())
    assert config["resumes"] == 1 and config["cost"]["multiplier"] == first
    rows = _rows(out / "progress.csv")
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    last = _check_dual_steps(rows[1:], first, 0.1, 0.2)
    assert config["cost"]["final_multiplier"] == pytest.approx(last, rel=1e-5)


def test_rllib_subtracts_the_weighted_cost_from_every_robots_reward(trained, tmp_path):
    """A fixed penalty (lr 0) of weight 2: the first iteration samples the same episodes
    as the plain run (same seeds, same initial policy), and its progress row records the
    environment's team return, as every trainer does: the plain run's. What RLlib learns
    from is lower, for every robot, by 2 times that robot's step cost."""
    out = tmp_path / "rllib"
    fixed = ["--cost", "magnitude", "--cost-weight", "2", "--multiplier-lr", "0"]
    _cost_run("rllib", out, 64, fixed, "--eval-every", "64", "--eval-episodes", "1")
    (plain,) = _rows(trained["rllib"] / "progress.csv")
    (row,) = _rows(out / "progress.csv")
    assert row["episodes"] == plain["episodes"] and float(row["multiplier"]) == 2.0
    assert float(row["episode_cost_mean"]) > 0.05
    assert float(row["episode_return_mean"]) == pytest.approx(
        float(plain["episode_return_mean"]), abs=1e-6
    )

    from baselines.rl.rllib_env import UVMSMultiAgentEnv

    config = {"scenario": "short", "overrides": {"max_cycles": 20}, "seed": 3}
    plain_env = UVMSMultiAgentEnv(config)
    cost_env = UVMSMultiAgentEnv({**config, "cost": {"kind": "magnitude"}})
    cost_env.set_multiplier(2.0)
    plain_env.reset()
    cost_env.reset()
    rng = np.random.default_rng(0)
    charged = 0
    for _ in range(10):
        actions = {a: rng.uniform(-1, 1, 8) for a in plain_env.possible_agents}
        _, r_plain, *_ = plain_env.step(actions)
        _, r_cost, _, _, infos = cost_env.step(actions)
        for a in plain_env.possible_agents:
            c = infos[a]["constraint_cost"]
            charged += c > 0
            assert r_cost[a] == pytest.approx(r_plain[a] - 2.0 * c, abs=1e-9)
    assert charged > 0


def test_sac_writes_the_same_records_and_a_last_row_at_the_budget(tmp_path):
    """SAC has no rollouts: a row every 256 steps of each sub-environment, and one for the
    steps after the last row when the budget is reached."""
    out = tmp_path / "sac"
    sac = ["--hp", "learning_starts=50", "--hp", "batch_size=16", "--hp", "buffer_size=1000"]
    sac += ["--hp", 'policy_kwargs={"net_arch": [8]}', "--num-envs", "1"]
    main(["--algo", "sac", "--robot-steps", "300", "--out", str(out), *TINY, *sac])
    assert _header(out / "progress.csv") == list(runs.PROGRESS_COLUMNS)
    progress = _rows(out / "progress.csv")
    assert [int(r["robot_steps"]) for r in progress] == [300]  # 150 steps of 2 robots
    assert int(progress[0]["episodes"]) == 150 // 6
    config = json.loads((out / "config.json").read_text())
    assert list(config) == list(CONFIG_KEYS) and config["algo"] == "sac"
    assert (out / "replay_buffer.pkl").exists()


@pytest.mark.parametrize("library", tuple(LIBRARIES))
def test_every_library_learns_with_the_channel_and_its_policy_sends(library, tmp_path, request):
    """``--comm``: the shared policy's action is the inputs, the send flag and the
    message; the run's evaluation plays under the same channel, and the saved policy
    reads the inbox and returns the full action."""
    if library == "rllib":
        request.getfixturevalue("local_ray")
    out = tmp_path / library
    args = ["--library", library, "--robot-steps", "64", "--out", str(out), "--comm", "atm900"]
    main([*args, *COMMON, *LIBRARY_ARGS[library]])
    config = json.loads((out / "config.json").read_text())
    assert config["overrides"]["comm"] == "atm900"
    evaluations = _rows(out / "evaluations.csv")
    assert evaluations and all(int(r["errors"]) == 0 for r in evaluations)

    import uvms_env
    from baselines.loaders.sources import PolicySource
    from uvms_env.episode import build_policies

    env = uvms_env.parallel_env("short", comm="atm900")
    obs, _ = env.reset(seed=0)
    name = {"sb3": "ppo", "benchmarl": "benchmarl", "rllib": "rllib"}[library]
    policies = build_policies(env, PolicySource.parse(f"{name}:{out}").factory(0))
    policy = policies["uvms_0"]
    assert policy.reads_messages
    action = policy.act(obs["uvms_0"])
    assert action.shape == (13,) and np.all(np.abs(action) <= 1.0 + 1e-6)
    env.step({a: policies[a].act(obs[a]) for a in env.possible_agents})


def test_comm_flag_contradicting_an_env_option_is_an_error(tmp_path, capsys):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as refused:  # a usage error, before the run folder
        main(["--comm", "atm900", "--env-option", 'comm="ideal"', "--out", str(out), *TINY])
    assert refused.value.code == 2 and not out.exists()
    assert "--comm atm900 contradicts --env-option comm='ideal'" in capsys.readouterr().err
