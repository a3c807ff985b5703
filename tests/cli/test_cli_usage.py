"""A newcomer's mistakes on the command lines: each is a usage error (exit status 2, no
traceback) that names the option and what it accepts, before any work (no run or output
folder); the evaluator's outputs survive episodes that all fail and name the failure; a
training budget rounded to whole rollouts is announced and the build is timed apart."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from help_in_process import help_in_process

from baselines import comm_sweep, evaluate, ladder, seeds, train
from baselines.imitation import cli as imitate
from nmpc_expert import __main__ as nmpc_expert

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py"))


def usage_error(main, argv: list[str], capsys) -> str:
    """``main(argv)``'s stderr, checked to be a usage error: exit 2, no traceback."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    assert "Traceback" not in err and "error:" in err
    return err


# -- the trainer --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--scenario", "nope"], ["--scenario", "'nope'", "paper", "random", "short"]),
        (["--n-agents", "1"], ["--n-agents", "2..8"]),
        (["--scenario", "paper", "--n-agents", "3"], ["--scenario paper", "exactly 2 agents"]),
        (["--scenario", "random", "--n-agents", "2", "9"], ["--n-agents", "2..8", "'9'"]),
        (["--robot-steps", "-5"], ["--robot-steps", "int >= 1", "'-5'"]),
        (["--robot-steps", "0"], ["--robot-steps", "int >= 1"]),
        (["--num-envs", "0"], ["--num-envs", "int >= 1"]),
        (["--n-agent", "3"], ["unrecognized arguments: --n-agent"]),
        (["--robot-step", "100"], ["unrecognized arguments: --robot-step"]),
        (["--mismatch", "0.7"], ["--mismatch", "[0, 0.5)"]),
        (["--mismatch", "0.2", "0.1"], ["--mismatch", "LOW HIGH"]),
        (["--env-option", "nope=1"], ["--env-option", "'nope'"]),
        (["--env-option", "n_agents"], ["--env-option", "KEY=VALUE"]),
        (["--hp", "nsteps=8"], ["--hp", "'nsteps'", "n_steps"]),
        (["--algo", "sac", "--central-critic"], ["--central-critic", "--algo ppo"]),
        (["--anchor", "0.5"], ["--anchor", "--init-actor"]),
        (["--library", "benchmarl", "--hp", "nope=1"], ["--hp", "'nope'", "SECTION.KEY"]),
        (["--library", "benchmarl", "--hp", "algorithm.nope=1"], ["--hp", "'nope'", "lmbda"]),
        (["--library", "benchmarl", "--hp", "experiment.max_n_frames=9"], ["--robot-steps"]),
        (["--library", "benchmarl", "--device", "gpu"], ["--device", "GPU index"]),
        (
            ["--library", "benchmarl", "--scenario", "random", "--n-agents", "2", "3"],
            ["--n-agents", "the benchmarl trainer takes one"],
        ),
        (["--library", "rllib", "--iterations", "0"], ["--iterations", "int >= 1"]),
        # an option that would be dropped is refused
        (["--cost-weight", "0.2"], ["--cost-weight", "without --cost"]),
        (["--cost-limit", "1", "--multiplier-lr", "0.1"], ["--cost-limit", "--multiplier-lr"]),
        (["--cost-limit-per", "period"], ["--cost-limit-per", "without --cost"]),
        (["--cost", "magnitude", "--cost-limit-per", "step"], ["--cost-limit-per", "'step'"]),
        (["--eval-ladder"], ["--eval-ladder", "without --eval-every"]),
        (["--eval-episodes", "3", "--eval-seed", "7"], ["--eval-seed", "--eval-episodes"]),
        (["--filter-penalty", "2"], ["--filter-penalty", "--filter"]),
    ],
)
def test_train_refuses_a_bad_value_naming_the_option(argv, named, tmp_path, capsys):
    out = tmp_path / "run"
    err = usage_error(train.main, [*argv, "--out", str(out)], capsys)
    assert all(n in err for n in named), err
    assert "usage: python -m baselines.train" in err
    assert not out.exists()  # refused before the run folder


def test_rllib_refuses_several_team_sizes_and_names_the_libraries_that_take_them(tmp_path, capsys):
    from baselines.registry import LIBRARIES, trainer_module

    several = [n for n in LIBRARIES if trainer_module(n).SEVERAL_TEAM_SIZES]
    assert "rllib" not in several and several  # the others deal copies into size groups
    argv = ["--library", "rllib", "--scenario", "random", "--n-agents", "2", "3"]
    err = usage_error(train.main, [*argv, "--out", str(tmp_path / "run")], capsys)
    assert "--n-agents" in err and "rllib" in err and ", ".join(several) in err
    # one size is honoured: it becomes the env's n_agents, no refusal
    args = train.build_parser("rllib").parse_args(["--scenario", "random", "--n-agents", "3"])
    settings = train.settings_from(args, {"num_envs": 1, "geometry_pool": None})
    assert settings.overrides["n_agents"] == 3 and settings.team_sizes == ()


def test_resume_of_a_missing_or_foreign_run_is_refused(tmp_path, capsys):
    err = usage_error(train.main, ["--resume", str(tmp_path / "nope")], capsys)
    assert "--resume" in err and "no such file or folder" in err
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"library": "benchmarl"}))
    argv = ["--library", "sb3", "--resume", str(other), "--out", str(other)]
    err = usage_error(train.main, argv, capsys)
    assert "--resume" in err and "trained with benchmarl, not sb3" in err
    # without --library a resume continues the run's own library: BenchMARL's check speaks
    err = usage_error(train.main, ["--resume", str(other), "--out", str(other)], capsys)
    assert "--resume" in err and "checkpoint_<frames>.pt" in err


def test_a_resume_continues_the_run_as_it_was_configured_in_its_own_folder(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    first = [
        "--scenario", "short", "--seed", "3", "--cost", "magnitude", "--cost-limit", "1",
        "--env-option", "observation_mode=memory",
        "--env-option", 'reward_weights={"violation": 0}',
        "--robot-steps", "1000", "--out", str(run),
    ]  # fmt: skip
    command = shlex.join(["python", "-m", "baselines.train", *first])
    (run / "config.json").write_text(json.dumps({"library": "sb3", "command": command}))
    ap = train.build_parser("sb3")

    def settings(argv):
        return train.settings_from(ap.parse_args(argv), {"num_envs": 2, "geometry_pool": None})

    # a resume naming only the budget keeps the cost, the reward, the seed and the folder
    again = train.resumed_argv(ap, ["--resume", str(run), "--robot-steps", "2000"])
    resumed, original = settings(again), settings(first)
    assert resumed.cost == original.cost and resumed.cost is not None
    assert resumed.overrides == original.overrides and resumed.seed == 3
    assert resumed.robot_steps == 2000 and resumed.out == run
    # what it names again replaces the recorded option (a next scenario; new env options)
    moved = settings(
        train.resumed_argv(
            ap, ["--resume", str(run), "--scenario", "random", "--env-option", "current=mild"]
        )
    )
    assert moved.scenario == "random" and moved.overrides["current"] == "mild"
    assert "reward_weights" not in moved.overrides and moved.cost == original.cost
    # the merged command is what the next resume reads: nothing is lost at the second
    (run / "config.json").write_text(
        json.dumps(
            {"library": "sb3", "command": shlex.join(["python", "-m", "baselines.train", *again])}
        )
    )
    twice = settings(train.resumed_argv(ap, ["--resume", str(run)]))
    assert twice.cost == original.cost and twice.robot_steps == 2000
    # without --out, a resume from a checkpoint goes on in the checkpoint's run
    checkpoint = run / "checkpoints" / "rl_model_64_steps.zip"
    checkpoint.parent.mkdir()
    checkpoint.touch()
    assert settings(["--resume", str(checkpoint)]).out == run


def test_a_usage_error_prints_no_traceback_from_the_command_line(tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "baselines.train", "--scenario", "nope"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "--scenario" in run.stderr and "usage: python -m baselines.train" in run.stderr


# -- the evaluator, the ladder, the sweep, the seeds ---------------------------------------------
@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--policy", "zero", "--scenario", "nope"], ["--scenario", "'nope'"]),
        (["--policy", "zero", "--n-agents", "1"], ["--n-agents", "2..8"]),
        (
            ["--policy", "zero", "--scenario", "paper", "--n-agents", "3"],
            ["scenario paper", "exactly 2 agents"],
        ),
        (["--policy", "zero", "--episodes", "0"], ["--episodes", "int >= 1"]),
        (["--policy", "zero", "--workers", "-1"], ["--workers", "int >= 1"]),
        (["--policy", "zero", "--episode", "1"], ["unrecognized arguments: --episode"]),
        (["--policy", "zeroo"], ["unknown policy 'zeroo'"]),
        (["--policy", "nmpc:nope"], ["policy nmpc:nope", "unknown nmpc option 'nope'"]),
        (["--policy", "zero", "--comm", "nope"], ["scenario paper", "unknown preset 'nope'"]),
    ],
)
def test_evaluate_refuses_before_any_episode(argv, named, tmp_path, capsys):
    out = tmp_path / "eval"
    err = usage_error(evaluate.main, [*argv, "--out", str(out)], capsys)
    assert all(n in err for n in named), err
    assert not out.exists()


def test_a_policy_that_cannot_be_loaded_fails_with_the_loaders_message(tmp_path, capsys):
    out, missing = tmp_path / "eval", tmp_path / "nope"
    argv = ["--policy", "zero", "--policy", f"ppo:{missing}", "--scenario", "short"]
    err = usage_error(evaluate.main, [*argv, "--out", str(out)], capsys)
    assert f"policy ppo:{missing} cannot be loaded" in err
    assert f"no SB3 model at {missing} (expected model.zip)" in err  # the loader's words
    assert not out.exists()  # no episode played, no table drawn
    argv = ["--policy", f"dagger:{missing}", "--n-agents", "2", "--no-paper", "--episodes", "1"]
    err = usage_error(ladder.main, [*argv, "--out", str(out)], capsys)
    assert f"policy dagger:{missing} cannot be loaded" in err and "policy.pt" in err
    assert not out.exists()


def test_the_ladder_sweep_and_seeds_check_their_values(tmp_path, capsys):
    out = str(tmp_path / "out")
    assert "--n-agents" in usage_error(ladder.main, ["--n-agents", "9", "--out", out], capsys)
    assert "--from" in usage_error(ladder.main, ["--from", f"{out}/nope.csv"], capsys)
    err = usage_error(comm_sweep.main, ["--bit-rates", "fast", "--out", out], capsys)
    assert "--bit-rates" in err and "'fast'" in err
    err = usage_error(comm_sweep.main, ["--latencies", "1.5", "--out", out], capsys)
    assert "--latencies" in err and "whole numbers" in err
    err = usage_error(seeds.main, [f"{out}/episodes.csv", "--group", "G=nmpc"], capsys)
    assert f"no such file or folder: {out}/episodes.csv" in err
    csv_path = tmp_path / "episodes.csv"
    csv_path.write_text("policy,scenario,episode,seed,error,success\nzero,short,0,1,,False\n")
    err = usage_error(seeds.main, [str(csv_path), "--group", "G"], capsys)
    assert "--group" in err and "NAME=POLICY" in err
    err = usage_error(seeds.main, [str(csv_path), "--group", "G=nmpc", "--out", out], capsys)
    assert "--group" in err and "['nmpc']" in err
    assert not Path(out).exists()


def failing_factory(spec):
    """A policy that builds (it loads) and fails at its first decision (a solver error)."""
    return _Fails()


class _Fails:
    def __init__(self) -> None:
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs):
        raise RuntimeError("solver diverged")


def test_the_evaluator_writes_every_output_when_every_episode_fails(tmp_path, capsys):
    policy = "tests.cli.test_cli_usage:failing_factory"
    out = tmp_path / "eval"
    argv = ["--policy", policy, "--scenario", "short", "--episodes", "2", "--workers", "1"]
    evaluate.main([*argv, "--max-cycles", "3", "--out", str(out)])
    for name in ("episodes.csv", "results.json", "results.md"):
        assert (out / name).stat().st_size > 0, name
    for name in ("success_by_scenario.png", "decision_time.png"):  # no decision: no crash
        assert (out / name).read_bytes()[:4] == b"\x89PNG", name
    (summary,) = json.loads((out / "results.json").read_text())
    assert summary["policy"] == policy and summary["errors"] == 2
    line = f"{policy}: 2 of 2 episodes failed; first (short, episode 0): RuntimeError: solver"
    assert line in (out / "results.md").read_text()
    assert f"failed: {line}" in capsys.readouterr().out  # on the console too


# -- the expert and the imitation command --------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--scenario", "nope"], ["--scenario", "'nope'"]),
        (["--n-agents", "1"], ["--n-agents", "2..8"]),
        (["--scenario", "paper", "--n-agents", "3"], ["--scenario paper", "exactly 2 agents"]),
        (["--max-cycles", "0"], ["--max-cycles", "int >= 1"]),
        (["--seed", "-1"], ["--seed", "int >= 0"]),
        (["--max-cycle", "10"], ["unrecognized arguments: --max-cycle"]),
    ],
)
def test_the_expert_refuses_before_building_its_controllers(argv, named, tmp_path, capsys):
    out = tmp_path / "expert"
    err = usage_error(nmpc_expert.main, [*argv, "--out", str(out)], capsys)
    assert all(n in err for n in named), err
    assert "usage: python -m nmpc_expert" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["collect", "--scenario", "paper", "--n-agents", "3"], ["--n-agents 3", "exactly 2"]),
        (["collect", "--expert", "ppo:nope"], ["--expert", "no SB3 model at nope"]),
        (["collect", "--episodes", "0"], ["--episodes", "int >= 1"]),
        (["collect", "--episode", "2"], ["unrecognized arguments: --episode"]),
        (["dagger", "--init", "dagger:pretrained", "--beta", "2"], ["--beta", "[0, 1]"]),
        (["dagger", "--init", "dagger:pretrained", "--scenario", "short:0"], ["--scenario"]),
        (["dagger", "--init", "bc:nope"], ["--init bc:nope", "policy.pt"]),
        (["dagger"], ["--data", "--init"]),
    ],
)
def test_imitate_refuses_before_any_rollout(argv, named, tmp_path, capsys):
    out = tmp_path / "data" / "x"
    err = usage_error(imitate.main, [*argv, "--out", str(out)], capsys)
    assert all(n in err for n in named), err
    assert "usage: python -m baselines.imitate" in err
    assert not out.parent.exists()


# -- every command names itself; every benchmark answers --help ----------------------------------
@pytest.mark.parametrize(
    ("main", "prog"),
    [
        (train.main, "baselines.train"),
        (evaluate.main, "baselines.evaluate"),
        (imitate.main, "baselines.imitate"),
        (ladder.main, "baselines.ladder"),
        (seeds.main, "baselines.seeds"),
        (comm_sweep.main, "baselines.comm_sweep"),
        (nmpc_expert.main, "nmpc_expert"),
    ],
)
def test_every_command_names_itself_in_its_usage(main, prog, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m {prog} ")


@pytest.mark.parametrize("script", BENCHMARKS)
def test_every_benchmark_answers_help(script):
    status, out = help_in_process((f"benchmarks/{script}",))
    assert status == 0, out[-2000:]
    assert out.startswith(f"usage: python benchmarks/{script}")


# -- the training budget and its clock -----------------------------------------------------------
class _Clock:
    """``time.perf_counter`` of ``baselines.runs``, moved by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_rounded_budget_is_announced_and_the_build_timed_apart(tmp_path, monkeypatch, capsys):
    from baselines import runs

    clock = _Clock()
    monkeypatch.setattr(runs, "time", SimpleNamespace(perf_counter=clock))
    settings = runs.RunSettings(
        robot_steps=20_000, out=tmp_path / "run", progress=False, record_eval=False,
        checkpoint_every=4096,
    )  # fmt: skip
    run = runs.Run.start(settings, "sb3", "ppo")
    clock.now += 30.0  # the env, its kernels and the model
    run.write_config()
    clock.now += 10.0  # the first reset
    assert run.begin(4096) == 20_480
    out = capsys.readouterr().out
    assert "--robot-steps 20000 rounds up to 20480: 5 rollouts of 4096 robot-steps" in out
    for k in range(1, 6):
        clock.now += 2.0
        run.iteration(4096 * k)
        if run.due("checkpoint_every", 4096 * k):
            with run.apart():
                clock.now += 5.0  # a checkpoint is no training
    config = run.finish(20_480)
    assert config["build_s"] == 40.0 and config["train_s"] == 10.0 and config["eval_s"] == 25.0
    assert config["robot_steps_per_s"] == 2048.0  # on the training time alone
    assert config["wall_time_s"] == 75.0
    rows = (tmp_path / "run" / "progress.csv").read_text().splitlines()[1:]
    assert [float(r.split(",")[-3]) for r in rows] == [2.0] * 5  # iteration_s: no checkpoint
    # a whole number of rollouts, or an iteration of unknown size: nothing to announce
    whole = runs.Run.start(runs.RunSettings(robot_steps=8192, out=tmp_path / "b"), "sb3", "ppo")
    assert whole.begin(4096) == 8192 and whole.begin(None) == 8192
    whole.close_bar()
    assert "rounds up" not in capsys.readouterr().out


# -- the geometry bank's builder ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["random", "--n-agent", "3"], ["unrecognized arguments: --n-agent"]),
        (["random", "--n-agents", "9"], ["--n-agents", "2..8", "'9'"]),
        (["random", "--workers", "0"], ["--workers", "int >= 1"]),
        (["random", "--seeds", "5:2"], ["--seeds", "START < STOP"]),
        (["random", "--seeds", "a:b"], ["--seeds", "START:STOP"]),
        (["nope"], ["family", "'nope'"]),
    ],
)
def test_the_bank_builder_refuses_a_bad_value_naming_the_option(argv, named, capsys):
    from uvms_env.scenarios import bank

    err = usage_error(bank.main, argv, capsys)
    assert all(n in err for n in named), err
    assert "usage: python -m uvms_env.vector.build_bank" in err


def test_the_audit_refuses_a_folder_that_is_no_run(tmp_path, capsys):
    from baselines.rl import audit

    err = usage_error(audit.main, [str(tmp_path)], capsys)
    assert "not a run folder" in err and str(tmp_path) in err
