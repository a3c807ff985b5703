"""Training on a distribution of team sizes and conditions, with memory: the shared
condition flags, ``ConcatVecEnv`` (one VecEnv per team size), MAPPO's padded state, the
SB3 trainer (PPO on the memory observation, RecurrentPPO) over several team sizes, their
evaluations under the run's conditions, the imitation CLI's
parallel rollouts over the distribution and the aggregate over training seeds. Tiny
budgets: these check the paths, not the learning."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from baselines.command_line import add_condition_arguments, condition_overrides, team_sizes
from baselines.train import build_parser, main, settings_from

pytest.importorskip("stable_baselines3")

# 6-step episodes, 2 copies per team size, a small pool of geometries, no checkpoints
TINY = [
    *("--scenario", "random", "--num-envs", "2", "--seed", "1", "--no-progress"),
    *("--env-option", "max_cycles=6", "--checkpoint-every", "0", "--geometry-pool", "4"),
    *("--n-agents", "2", "3", "--current", "none", "mild", "--mismatch", "0", "0.1"),
    *("--eval-max-cycles", "30"),
]
SB3_TINY = ["--hp", "n_steps=8", "--hp", "batch_size=16", "--hp", "n_epochs=1"]
MEMORY = ["--env-option", "action_mode=residual", "--env-option", "observation_mode=memory"]


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _parsed(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    add_condition_arguments(ap)
    return ap.parse_args(argv)


# -- flags ------------------------------------------------------------------------------------
def test_condition_flags_become_overrides_and_draws():
    args = _parsed(["--n-agents", "2", "4", "4", "--current", "none", "mild", "--mismatch", "0.1"])
    assert team_sizes(args) == (2, 4)
    assert condition_overrides(args) == {
        "mismatch": 0.1,
        "randomize": {"current": ["none", "mild"]},
    }
    args = _parsed(["--current", "mild", "--mismatch", "0", "0.2"])
    assert condition_overrides(args) == {"current": "mild", "randomize": {"mismatch": [0.0, 0.2]}}
    with pytest.raises(ValueError, match="LOW HIGH"):
        condition_overrides(_parsed(["--mismatch", "0.2", "0.1"]))


def test_trainer_settings_from_the_condition_flags():
    defaults = {"num_envs": 4, "geometry_pool": 8}

    def settings(*argv: str):
        return settings_from(build_parser("sb3").parse_args(list(argv)), defaults)

    s = settings("--scenario", "random", "--n-agents", "2", "3", "4")
    assert s.team_sizes == (2, 3, 4) and "n_agents" not in s.overrides
    s = settings("--scenario", "random", "--n-agents", "5")
    assert s.team_sizes == () and s.overrides["n_agents"] == 5
    with pytest.raises(ValueError, match="once"):
        settings("--scenario", "random", "--n-agents", "2", "3", "--env-option", "n_agents=2")
    with pytest.raises(ValueError, match="--scenario paper --n-agents 3: the paper scenario"):
        settings("--scenario", "paper", "--n-agents", "2", "3")
    with pytest.raises(ValueError, match="contradicts"):
        settings("--current", "mild", "--env-option", 'current="none"')
    # several objects: one group of env copies per (team size, object), a rung each
    s = settings("--scenario", "random", "--n-agents", "2", "3", "--object", "ring", "bar")
    assert s.objects == ("ring", "bar") and "object" not in s.overrides
    assert [(g["n_agents"], g["object"]) for g in s.groups()] == [
        (2, "ring"), (2, "bar"), (3, "ring"), (3, "bar")
    ]  # fmt: skip
    assert all(g["internal_wrench_every"] == 0 for g in s.groups())  # the training defaults
    assert list(s.rungs()) == ["random_n2_ring", "random_n2_bar", "random_n3_ring", "random_n3_bar"]
    assert s.rungs()["random_n3_bar"][1]["object"] == "bar"
    s = settings("--scenario", "random", "--object", "bar", "--course", "turns")
    assert s.objects == () and (s.overrides["object"], s.overrides["course"]) == ("bar", "turns")
    assert list(s.rungs()) == ["random"] and s.rungs()["random"][1]["course"] == "turns"
    with pytest.raises(ValueError, match="--object ring: object: only the random family"):
        settings("--scenario", "short", "--object", "ring", "bar")


# -- the VecEnv over several team sizes ---------------------------------------------------------
def test_concat_vec_env_steps_each_part_as_alone():
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import ConcatVecEnv, VectorVecEnv

    def part(n: int, seed: int) -> VectorVecEnv:
        return VectorVecEnv(VectorEnv("random", num_envs=2, n_agents=n, max_cycles=5), seed=seed)

    both = ConcatVecEnv([part(2, 3), part(3, 4)])
    alone = [part(2, 3), part(3, 4)]
    assert both.num_envs == 2 * 2 + 2 * 3
    assert both.team_leaders.tolist() == [1, 0, 1, 0, 1, 0, 0, 1, 0, 0]
    obs = both.reset()
    np.testing.assert_array_equal(obs, np.concatenate([p.reset() for p in alone]))
    rng = np.random.default_rng(0)
    for _ in range(7):  # past an episode end: the parts reset on their own
        act = rng.uniform(-0.5, 0.5, (both.num_envs, 8)).astype(np.float32)
        got = both.step(act)
        want = [alone[0].step(act[:4]), alone[1].step(act[4:])]
        np.testing.assert_array_equal(got[0], np.concatenate([w[0] for w in want]))
        np.testing.assert_array_equal(got[1], np.concatenate([w[1] for w in want]))
        np.testing.assert_array_equal(got[2], np.concatenate([w[2] for w in want]))
        assert [i.get("cost") for i in got[3]] == [i.get("cost") for w in want for i in w[3]]
        values = [a.last_infos["constraint_values"].reshape(-1, 8) for a in alone]
        np.testing.assert_array_equal(both.last_infos["constraint_values"], np.concatenate(values))
    assert both.get_attr("n", [0, 5]) == [2, 3]
    features = VectorEnv("random", num_envs=1, n_agents=2, observation_mode="features")
    with pytest.raises(ValueError, match="observation space"):
        ConcatVecEnv([part(2, 3), VectorVecEnv(features)])


def test_mappo_state_padded_to_the_largest_team():
    from baselines.rl.mappo import CentralStateVecEnv
    from uvms_env.dynamics import NQ
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv

    inner = VectorEnv("random", num_envs=2, n_agents=2, max_cycles=5)
    padded = CentralStateVecEnv(VectorVecEnv(inner, seed=0), max_agents=4)
    obs = padded.reset()
    local, state = obs[:, : padded.local_dim], obs[:, padded.local_dim :]
    raw = inner.state()
    assert state.shape[1] == 4 * 2 * NQ + 19 + 4
    robots = 2 * NQ
    np.testing.assert_array_equal(state[0, :robots], raw[0, :robots])  # q of both robots
    assert not state[:, robots : 2 * robots].any()  # q of the two absent ones
    np.testing.assert_array_equal(state[0, 2 * robots : 3 * robots], raw[0, robots : 2 * robots])
    np.testing.assert_array_equal(state[:, -4:], [[1, 1, 0, 0]] * 4)
    assert local.shape[1] == 79
    with pytest.raises(ValueError, match="below the team size"):
        CentralStateVecEnv(VectorVecEnv(inner, seed=0), max_agents=1)


# -- the trainers over several team sizes -------------------------------------------------------
@pytest.fixture(scope="module")
def memory_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist") / "ppo_memory"
    main(["--library", "sb3", "--robot-steps", "100", "--eval-every", "50", "--eval-episodes", "1",
          "--eval-seed", "7", "--out", str(out), "--cost", "magnitude", *TINY, *SB3_TINY,
          *MEMORY])  # fmt: skip
    return out


def test_sb3_trains_over_team_sizes_and_evaluates_under_the_runs_conditions(memory_run):
    config = json.loads((memory_run / "config.json").read_text())
    assert config["team_sizes"] == [2, 3] and config["eval_seed"] == 7
    assert config["library_settings"]["robot_sub_envs"] == 2 * (2 + 3)
    assert config["overrides"]["randomize"] == {"current": ["none", "mild"], "mismatch": [0, 0.1]}
    rows = _rows(memory_run / "evaluations.csv")
    assert [r["rung"] for r in rows[:2]] == ["random_n2", "random_n3"]
    assert all(float(r["violation_periods_median"]) >= 0 for r in rows)
    assert config["eval_max_cycles"] == 30  # the evaluations and the record capped
    assert all(float(r["episode_steps"]) <= 30 for r in rows)
    assert all(e["episode_steps"] <= 30 for e in config["eval"]["episodes"])
    best = json.loads((memory_run / "best" / "config.json").read_text())  # early stopping
    assert best["best"] == config["best"] and best["best"]["robot_steps"] in {
        int(r["robot_steps"]) for r in rows
    }
    assert best["robot_steps"] == best["best"]["robot_steps"]
    assert len(best["eval"]["episodes"]) == len(config["eval"]["episodes"])
    assert (memory_run / "best" / "model.zip").is_file()


def test_memory_policy_decides_compiled_as_with_predict(memory_run):
    """The compiled decision of a PPO actor on the memory observation rebuilds the robot's
    memory as the environment did and matches SB3's predict (numpy priors) step by step."""
    import uvms_env
    from baselines.loaders.sb3_policy import SB3Policy
    from uvms_env.policy import AgentSpec

    env = uvms_env.parallel_env("random", n_agents=3, current="mild", mismatch=0.1)
    obs, _ = env.reset(seed=5)
    spec = AgentSpec.from_scenario(env.scenario, 1)
    fast, slow = SB3Policy(spec, "ppo", memory_run), SB3Policy(spec, "ppo", memory_run, False)
    assert fast.compiled and not slow.compiled
    for _ in range(6):
        a, b = fast.act(obs["uvms_1"]), slow.act(obs["uvms_1"])
        np.testing.assert_allclose(a, b, rtol=0, atol=2e-5)
        obs, *_ = env.step({x: a if x == "uvms_1" else np.zeros(8) for x in env.agents})
    assert fast.inputs.memory.observe(obs["uvms_1"])[:8].any()  # it remembers what it sent


def test_recurrent_ppo_trains_and_its_state_restarts_each_episode(tmp_path):
    pytest.importorskip("sb3_contrib")
    import uvms_env
    from baselines.loaders.sb3_policy import SB3Policy
    from uvms_env.policy import AgentSpec

    out = tmp_path / "rppo"
    main(["--library", "sb3", "--algo", "recurrent_ppo", "--robot-steps", "80", "--out", str(out),
          *TINY, *SB3_TINY, "--hp", 'policy_kwargs={"lstm_hidden_size": 8}'])  # fmt: skip
    env = uvms_env.parallel_env("random", n_agents=2)
    obs, _ = env.reset(seed=2)
    policy = SB3Policy(AgentSpec.from_scenario(env.scenario, 0), "recurrent_ppo", out)
    stream = [obs["uvms_0"]]
    for _ in range(4):
        obs, *_ = env.step({a: np.zeros(8) for a in env.agents})
        stream.append(obs["uvms_0"])
    first = [policy.act(o) for o in stream]
    policy.reset()
    again = [policy.act(o) for o in stream]
    np.testing.assert_array_equal(np.stack(first), np.stack(again))
    # the LSTM carries something: the same observation twice is not the same decision
    assert not np.array_equal(policy.act(stream[0]), first[0])


# -- imitation over the distribution --------------------------------------------------------
def test_parallel_rollouts_equal_one_process_and_cycle_the_team_sizes():
    from baselines.imitation.labelled_rollouts import RolloutJob, parallel_rollouts

    job = RolloutJob(
        "random",
        {"randomize": {"current": ["none", "mild"]}, "internal_wrench_every": 0},
        (2, 3),
        cap=5,
        expert="experts.scripted:expert",
        noise=0.05,
    )
    one, m1 = parallel_rollouts(job, 4, 40, workers=1, progress=False)
    two, m2 = parallel_rollouts(job, 4, 40, workers=2, progress=False)
    assert len(one) == 2 + 3 + 2 + 3 and len(m1) == len(m2) == 4
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(np.stack(a.observations), np.stack(b.observations))
        np.testing.assert_array_equal(np.stack(a.actions), np.stack(b.actions))
        np.testing.assert_array_equal(np.stack(a.memory), np.stack(b.memory))
        assert len(a.memory) == len(a.observations)


def test_a_rollout_job_meets_every_team_size_with_every_object():
    from baselines.imitation.labelled_rollouts import RolloutJob

    job = RolloutJob("random", {"internal_wrench_every": 0}, (2, 3), objects=("ring", "bar"))
    played = [job.env(100 + e, e) for e in range(8)]
    kinds = [(env.n, env.scenario.object_shape) for env in played]
    assert kinds[:4] == [(2, "ring"), (3, "ring"), (2, "bar"), (3, "bar")]
    assert kinds[4:] == kinds[:4]  # then again, in the same order


def test_dagger_evaluates_every_team_size_with_every_object():
    import argparse

    from baselines.imitation.cli import dagger_rungs

    args = argparse.Namespace(n_agents=[2, 3], object=["ring", "bar"], course=None, current=None,
                              mismatch=None, constraint_mode=None, max_cycles=None,
                              expert="nmpc")  # fmt: skip
    rungs = dagger_rungs(args, ["random:4", "paper:1"])
    assert set(rungs) == {"random_ring_n2", "random_bar_n2", "random_ring_n3",
                          "random_bar_n3", "paper"}  # fmt: skip
    assert rungs["random_bar_n3"][1]["object"] == "bar"
    assert rungs["random_bar_n3"][1]["n_agents"] == 3
    assert "object" not in rungs["paper"][1] and "n_agents" not in rungs["paper"][1]


def test_imitation_refuses_an_object_for_a_scenario_that_keeps_its_own(capsys):
    from baselines.imitation.cli import main as imitate

    with pytest.raises(SystemExit) as refused:
        imitate(["collect", "--scenario", "paper", "--object", "bar", "--episodes", "1",
                 "--out", "unused"])  # fmt: skip
    assert refused.value.code == 2
    assert "--object: only the random family draws an object, not paper" in (
        capsys.readouterr().err
    )


def test_imitation_cli_collects_and_clones_memory_over_the_distribution(tmp_path):
    pytest.importorskip("minari")
    import uvms_env
    from baselines.imitation.cli import main as imitate
    from baselines.imitation.dataset import read_many
    from baselines.loaders.clone_policy import ClonedPolicy
    from baselines.networks.mlp import MLPPolicyNet
    from uvms_env.policy import AgentSpec
    from uvms_env.robot.memory import RobotMemory

    data = tmp_path / "data" / "dist"
    imitate(["collect", "--scenario", "random", "--n-agents", "2", "3", "--current", "none",
             "mild", "--mismatch", "0", "0.1", "--episodes", "2", "--max-cycles", "6",
             "--workers", "2", "--expert", "experts.scripted:expert", "--noise", "0.05",
             "--out", str(data)])  # fmt: skip
    obs, act, _, streams = read_many([data], memory=True)
    assert streams == 5 and obs.shape == (5 * 6, 79 + 16) and act.shape == (5 * 6, 8)
    out = tmp_path / "bc"
    imitate(["bc", "--data", str(data), "--features", "memory", "--epochs", "2",
             "--hidden", "8", "--out", str(out)])  # fmt: skip
    net = MLPPolicyNet.load(out / "policy.pt")
    assert net.features == "memory"
    env = uvms_env.parallel_env("random", n_agents=3)
    o, _ = env.reset(seed=1)
    spec = AgentSpec.from_scenario(env.scenario, 0)
    ring = spec.object_key
    policy, memory = ClonedPolicy(spec, out / "policy.pt"), RobotMemory(spec.period, ring)
    policy.reset()
    for _ in range(4):
        x = np.concatenate([o["uvms_0"], memory.observe(o["uvms_0"])])
        a = policy.act(o["uvms_0"])
        np.testing.assert_allclose(a, net.predict(x[None], spec.object_key)[0],
                                   atol=1e-5)  # fmt: skip
        memory.issued(a)
        o, *_ = env.step({x_: a if x_ == "uvms_0" else np.zeros(8) for x_ in env.agents})


# -- over training seeds ----------------------------------------------------------------------
def test_seed_aggregate_is_rliables_iqm_of_the_seed_by_case_scores(tmp_path):
    pytest.importorskip("rliable")
    from baselines.seeds import main as seeds_main

    rng = np.random.default_rng(0)
    rows, rates = [], np.zeros((3, 2))
    for s in range(3):
        for j, case in enumerate(("random N=2", "paper")):
            wins = rng.random(10) < 0.3 + 0.2 * s
            rates[s, j] = wins.mean()
            for e, w in enumerate(wins):
                rows.append({"policy": f"p{s}", "scenario": case, "episode": e,
                             "success": w, "clean_success": False,
                             "violation_periods": 10 * s + e,
                             "return": -100.0 * s + e})  # fmt: skip
    paths = [tmp_path / "a.csv", tmp_path / "b.csv"]  # runs played apart, read as one
    for path, part in zip(paths, (rows[:20], rows[20:]), strict=True):
        with open(path, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(part)
    seeds_main([*map(str, paths), "--group", "G=p0,p1,p2", "--out", str(tmp_path / "out")])
    summary = json.loads((tmp_path / "out" / "seeds.json").read_text())["G"]
    success = summary["metrics"]["success"]
    np.testing.assert_allclose(success["per_seed"], rates)
    point, low, high = success["iqm"]
    assert point == pytest.approx(stats.trim_mean(rates.reshape(-1), 0.25))
    assert low <= point <= high
    assert summary["metrics"]["violation_periods"]["per_seed"][2] == [24.5, 24.5]
    assert summary["metrics"]["return"]["per_seed"][1] == [-95.5, -95.5]  # mean of -100 + e
    assert summary["cases"] == ["random N=2", "paper"]
    from baselines.stats import iqm_and_mean

    assert iqm_and_mean(rates, seed=3) == iqm_and_mean(rates, seed=3)  # reproducible


def test_the_committed_seed_rule_ranks_clean_then_success_then_lower_excess():
    from baselines.seeds import rank_by_rule

    def rows(policy: str, clean: int, success: int, excess: list[float]) -> list[dict]:
        return [{"policy": policy, "scenario": case, "episode": e,
                 "clean_success": 2 * j + e < clean, "success": 2 * j + e < success,
                 "excess": excess[2 * j + e]}
                for j, case in enumerate(("random N=2", "paper")) for e in range(2)]  # fmt: skip

    table = [
        *rows("a", 2, 3, [0.0, 0.0, 1.0, 3.0]),  # mean excess 1.0
        *rows("b", 2, 3, [0.0, 0.0, 0.2, 0.2]),  # same counts as a, lower excess: first
        *rows("c", 3, 3, [9.0, 9.0, 9.0, 9.0]),  # most clean successes: first, whatever else
        *rows("d", 2, 4, [5.0, 5.0, 5.0, 5.0]),  # a's clean count, one more success
    ]
    ranked = rank_by_rule(table, ["a", "b", "c", "d"])
    assert [k["policy"] for k in ranked] == ["c", "d", "b", "a"]
    assert ranked[2] == {"policy": "b", "clean_success": 2, "success": 3,
                         "excess": pytest.approx(0.1), "episodes": 4}  # fmt: skip
    table[-1]["excess"] = None  # an episode the policy failed to play: no excess
    assert rank_by_rule(table, ["d"])[0]["excess"] == pytest.approx(5.0)
    with pytest.raises(ValueError, match="same episodes"):
        rank_by_rule(table[:-1], ["a", "d"])  # d lacks one of a's episodes


def test_dagger_warm_starts_and_evaluates_each_iteration_per_team_size(tmp_path):
    """``--warm-start E``: iterations fine-tune the previous network for E epochs;
    ``--eval-episodes``: each iteration's network on every team size under the run's
    conditions, at the labelled robot-steps so far (evaluations.csv, the trainers' schema)."""
    pytest.importorskip("minari")
    from baselines.evaluation.during_training import EVAL_COLUMNS
    from baselines.imitation.cli import main as imitate

    data = tmp_path / "data" / "demo"
    expert = "experts.scripted:expert"
    conditions = ["--n-agents", "2", "3", "--current", "none", "mild", "--max-cycles", "5"]
    imitate(["collect", "--scenario", "random", "--episodes", "2", "--expert", expert,
             "--out", str(data), *conditions])  # fmt: skip
    out = tmp_path / "dagger"
    imitate(["dagger", "--data", str(data), "--features", "memory", "--epochs", "3",
             "--warm-start", "1", "--hidden", "8", "--scenario", "random:2", "--iterations", "2",
             "--expert", expert, "--eval-episodes", "1", "--eval-seed", "9",
             "--eval-max-cycles", "5", "--out", str(out), *conditions])  # fmt: skip
    losses = _rows(out / "dagger_loss.csv")
    epochs = {stage: sum(r["stage"] == stage for r in losses) for stage in ("dagger_0", "dagger_1")}
    assert epochs == {"dagger_0": 3, "dagger_1": 1}
    rows = _rows(out / "evaluations.csv")
    assert list(rows[0]) == list(EVAL_COLUMNS)
    assert [r["rung"] for r in rows] == ["random_n2", "random_n3"] * 3  # iterations 0, 1, 2
    steps = [int(r["robot_steps"]) for r in rows[::2]]
    assert steps[0] == (2 + 3) * 5 and steps[0] < steps[1] < steps[2]
    info = json.loads((out / "train.json").read_text())
    assert info["warm_start_epochs"] == 1 and info["n_agents"] == [2, 3]


def test_dagger_resumes_to_the_network_of_an_uninterrupted_run(tmp_path, capsys, monkeypatch):
    """``--resume RUN`` (a run saved with --save-data) continues from the last iteration's
    network and aggregate, also a run stopped before its first iteration ended: the resumed
    runs' networks are the straight run's, bit for bit."""
    pytest.importorskip("minari")
    import torch

    from baselines.imitation import cli
    from baselines.imitation.cli import main as imitate

    data = tmp_path / "data" / "demo"
    expert = "experts.scripted:expert"
    env = ["--n-agents", "2", "3", "--max-cycles", "4"]
    imitate(["collect", "--scenario", "random", "--episodes", "2", "--expert", expert,
             "--out", str(data), *env])  # fmt: skip
    common = ["--data", str(data), "--features", "memory", "--epochs", "2", "--warm-start", "1",
              "--hidden", "8", "--scenario", "random:2", "--expert", expert, "--save-data",
              "--noise", "0.05", "--beta", "0.5", *env]  # fmt: skip
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    imitate(["dagger", *common, "--iterations", "2", "--out", str(straight)])
    imitate(["dagger", *common, "--iterations", "1", "--out", str(resumed)])
    imitate(["dagger", *common, "--iterations", "2", "--resume", str(resumed)])
    killed = tmp_path / "killed"  # stopped during the first iteration's rollouts

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(cli, "_dagger_iteration", stopped)
        with pytest.raises(KeyboardInterrupt):
            imitate(["dagger", *common, "--iterations", "2", "--out", str(killed)])
    imitate(["dagger", *common, "--iterations", "2", "--resume", str(killed)])
    a = torch.load(straight / "policy.pt", weights_only=False)["state"]
    for run in (resumed, killed):
        b = torch.load(run / "policy.pt", weights_only=False)["state"]
        for key in a:
            assert torch.equal(a[key], b[key]), (run.name, key)
    info = json.loads((resumed / "train.json").read_text())
    assert [h["iteration"] for h in info["history"]] == [0, 1, 2]
    unsaved = [a for a in common if a != "--save-data"]
    with pytest.raises(SystemExit) as refused:
        imitate(["dagger", *unsaved, "--iterations", "3", "--resume", str(resumed)])
    assert refused.value.code == 2 and "--resume needs --save-data" in capsys.readouterr().err


def test_anchor_penalty_is_the_distance_to_the_clones_residual():
    """``AnchorPenalty``: each robot's reward minus W mean((s a - clip(r_c, -s, s))^2),
    r_c the clone's residual on the observation the action answered: zero for the clone's
    own action, the formula otherwise (recomputed here from the network's layers)."""
    import torch

    from baselines.networks.mlp import MLPPolicyNet
    from baselines.rl.anchor import AnchorPenalty
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv

    def venv() -> VectorVecEnv:
        inner = VectorEnv("random", num_envs=2, n_agents=2, observation_mode="memory",
                          action_mode="residual", residual_scale=0.5, max_cycles=5)  # fmt: skip
        return VectorVecEnv(inner, seed=3)

    plain = venv()
    obs = plain.reset()
    rng = np.random.default_rng(0)
    data = np.concatenate([obs.repeat(8, 0)[:, :-8] + rng.normal(0, 0.1, (32, 92)),
                           obs.repeat(8, 0)[:, -8:]], 1).astype(np.float32)  # fmt: skip
    # a clone on the memory inputs (its weights at random: the wrapper reads any network)
    clone = MLPPolicyNet(100, 8, (8,), features="memory")
    clone.set_normalization(data)
    anchored = AnchorPenalty(venv(), clone, 0.5, 3.0)
    assert np.array_equal(anchored.reset(), obs)
    with torch.no_grad():
        x = torch.as_tensor(obs)
        residual = (clone(x) - x[:, -8:]).numpy()
    for actions, expected_zero in ((np.clip(residual / 0.5, -1, 1), True),
                                   (rng.uniform(-1, 1, residual.shape), False)):  # fmt: skip
        plain_step = plain.step(actions.astype(np.float32))
        got = anchored.step(actions.astype(np.float32))
        target = np.clip(residual, -0.5, 0.5)
        penalty = 3.0 * np.mean((0.5 * np.clip(actions, -1, 1) - target) ** 2, axis=1)
        np.testing.assert_allclose(plain_step[1] - got[1], penalty, rtol=1e-5, atol=1e-6)
        assert (penalty.max() < 1e-10) == expected_zero
        assert [i["anchor_penalty"] for i in got[3]] == pytest.approx(penalty.tolist())
        with torch.no_grad():
            x = torch.as_tensor(got[0])
            residual = (clone(x) - x[:, -8:]).numpy()
    with pytest.raises(ValueError, match="reads 100 numbers"):
        AnchorPenalty(VectorVecEnv(VectorEnv("random", num_envs=1, n_agents=2)), clone, 0.5, 1.0)


def test_the_audit_tables_read_a_tiny_runs_records(memory_run):
    """``baselines.rl.audit``: each rung's first and last evaluation as the CSV holds them,
    the early-end share and the objective over the progress rows' quarters."""
    from baselines.rl.audit import markdown, start_and_end, training_quarters

    evaluations = _rows(memory_run / "evaluations.csv")
    table = start_and_end(memory_run)
    assert [r["rung"] for r in table] == ["random_n2", "random_n3"]
    for row in table:
        mine = [e for e in evaluations if e["rung"] == row["rung"]]
        assert row["steps_start"] == float(mine[0]["robot_steps"])
        assert row["steps_end"] == float(mine[-1]["robot_steps"]) > row["steps_start"]
        assert row["return_end"] == pytest.approx(float(mine[-1]["mean_return"]))
        assert row["clean_end"] == float(mine[-1]["clean_success_rate"])
    progress = _rows(memory_run / "progress.csv")
    q = training_quarters(memory_run)
    assert q is not None and q["iterations"] == len(progress)
    quarter = max(1, len(progress) // 4)
    last = progress[-quarter:]
    ended = sum(float(r[k]) for r in last for k in r if k.startswith("ends_"))
    assert q["episodes_last"] == int(ended)
    multiplier = np.mean([float(r["multiplier"]) for r in last])
    assert q["multiplier_last"] == pytest.approx(multiplier)
    text = markdown([memory_run])
    assert text.count("| ppo_memory | random_n") == 2 and "ended early" in text
