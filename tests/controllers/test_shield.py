"""Shielded training (``baselines.rl.shield``): the training filter decides as the
evaluation's ``+filter`` does on the same inputs, each robot's filter reads only its own
observation, the learner keeps its proposal and pays W |a_safe - a_prop|^2, and a tiny
``--filter`` run writes the run layer's records."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from baselines.loaders.clone_policy import ClonedPolicy
from baselines.rl.shield import SHIELD_COLUMNS, Shield, ShieldPenalty
from nmpc_expert import make_filter
from uvms_env.policy import AgentSpec
from uvms_env.robot.priors import steady_inputs
from uvms_env.vector import VectorEnv

K, N = 2, 2
OPTIONS = {"n_agents": N, "internal_wrench_every": 0, "geometry_pool": 16}


def _env(**options) -> VectorEnv:
    return VectorEnv("random", num_envs=K, dtype="float64", threads=1, **OPTIONS, **options)


class Residual:
    """An evaluation-time inner policy: the command its residual ``r`` makes under the
    environment's priors (as ``SB3Policy`` returns it)."""

    def __init__(self, priors, ring: float) -> None:
        self.priors, self.ring = priors, ring
        self.r = np.zeros(8)
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.priors.command(np.asarray(obs, np.float64), self.r, self.ring)


def test_the_training_filter_decides_as_the_evaluation_filter():
    """Residual mode: the shield filters the command clip(a_ss + s r); the evaluation's
    filter around a policy proposing that command, fed the same observations, returns the
    same input to 1e-9: unchanged where it judges the proposal safe, corrected where not."""
    env = _env(action_mode="residual", observation_mode="raw", residual_scale=1.0)
    shield = Shield(env, penalty=2.0)
    obs, _ = env.reset(seed=3)
    ring = env.scenarios[0].object_key
    inner = [[Residual(env.priors, ring) for _ in range(N)] for _ in range(K)]
    ref = [
        [
            make_filter(lambda spec, p=inner[k][i]: p)(AgentSpec.from_scenario(env.scenarios[k], i))
            for i in range(N)
        ]
        for k in range(K)
    ]
    for row in ref:
        for f in row:
            f.reset()
    clones = [
        ClonedPolicy(
            AgentSpec.from_scenario(env.scenarios[0], i), ClonedPolicy.locate("dagger", None)
        )
        for i in range(N)
    ]
    rng = np.random.default_rng(0)
    passed = corrected = 0
    for t in range(12):
        # first the DAgger clone's commands (as residuals around a_ss: safe proposals),
        # then large random residuals
        if t < 6:
            steady = steady_inputs(obs, ring)
            clone = np.array([[clones[i].act(obs[k, i]) for i in range(N)] for k in range(K)])
            r = clone - steady
        else:
            r = rng.uniform(-1, 1, (K, N, 8))
        expected = np.zeros((K, N, 8))
        intervened = np.zeros((K, N), bool)
        for k in range(K):
            for i in range(N):
                inner[k][i].r = r[k, i]
                expected[k, i] = ref[k][i].act(obs[k, i])
                intervened[k, i] = ref[k][i].stats["intervened"]
        obs, *_ = env.step(r)
        np.testing.assert_allclose(shield.safe, expected, atol=1e-9, rtol=0)
        deviation = np.abs(shield.safe - shield.proposal).max(-1)
        assert np.all(deviation[~intervened] <= 1e-3)  # a safe proposal passes
        passed += int((~intervened).sum())
        corrected += int((deviation > 0.05).sum())
        np.testing.assert_allclose(
            shield.penalty, 2.0 * ((shield.safe - shield.proposal) ** 2).sum(-1), rtol=1e-12
        )
    assert passed > 0 and corrected > 0


def test_the_proposal_is_the_command_of_the_action():
    """What the shield receives is the environment's command of the learner's action."""
    env = _env(action_mode="residual", observation_mode="raw", residual_scale=0.3)
    shield = Shield(env)
    obs, _ = env.reset(seed=5)
    r = np.random.default_rng(1).uniform(-1, 1, (K, N, 8))
    steady = steady_inputs(obs, env.scenarios[0].object_key)
    env.step(r)
    np.testing.assert_allclose(shield.proposal, np.clip(steady + 0.3 * r, -1, 1), atol=1e-9)


def test_each_robots_filter_reads_only_its_own_observation_and_proposal():
    env = _env()
    obs, _ = env.reset(seed=7)
    rng = np.random.default_rng(2)
    proposal = rng.uniform(-1, 1, (K, N, 8))
    first = np.ones(K, bool)
    a = Shield(env)(obs, proposal, first)
    other = obs.copy()
    other[:, 1] += rng.normal(0, 0.05, other[:, 1].shape)  # robot 1's view and proposal
    changed = proposal.copy()
    changed[:, 1] = rng.uniform(-1, 1, (K, 8))
    b = Shield(env)(other, changed, first)
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    assert np.abs(a[:, 1] - b[:, 1]).max() > 0


def test_the_rollout_stores_the_proposal_and_the_reward_pays_the_correction():
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from uvms_env.vector.sb3 import VectorVecEnv

    weight = 3.0
    base = VectorVecEnv(_env(), seed=11)
    shield = Shield(base.vector_env, penalty=weight)
    venv = ShieldPenalty(base, shield)
    seen: list[tuple] = []

    class Record(BaseCallback):
        def _on_step(self) -> bool:
            terms = base.last_infos["reward_terms"]
            team = sum(np.broadcast_to(v, (K,)) for v in terms.values())
            seen.append(
                (
                    shield.proposal.copy(),
                    shield.safe.copy(),
                    np.asarray(self.locals["rewards"]).copy(),
                    np.repeat(team, N),
                    [info["filter_penalty"] for info in self.locals["infos"]],
                )
            )
            return True

    steps = 8
    model = PPO("MlpPolicy", venv, n_steps=steps, batch_size=16, n_epochs=1, seed=0, device="cpu")
    model.learn(steps * K * N, callback=Record())
    # the buffer after the update: flattened robot-major, (K N steps, 8)
    stored = np.clip(model.rollout_buffer.actions, -1, 1).reshape(K * N, steps, 8)
    stored = stored.transpose(1, 0, 2)
    assert len(seen) == steps
    moved = 0
    for t, (proposal, safe, reward, team, penalty) in enumerate(seen):
        np.testing.assert_allclose(stored[t], proposal.reshape(K * N, 8), atol=1e-6)
        expected = weight * ((safe - proposal) ** 2).sum(-1).reshape(-1)
        np.testing.assert_allclose(penalty, expected, rtol=1e-12)
        np.testing.assert_allclose(reward, team - expected, rtol=1e-5, atol=1e-5)
        moved += int((np.abs(safe - proposal).max(-1) > 1e-3).sum())
    assert moved > 0  # the filter acted, so the stored proposals are not what ran


def test_a_filtered_training_run_writes_the_run_records(tmp_path):
    from baselines.train import main

    out = tmp_path / "run"
    main(
        [
            "--library", "sb3", "--algo", "ppo", "--scenario", "random",
            "--env-option", "n_agents=2", "--num-envs", "2", "--hp", "n_steps=64",
            "--robot-steps", "512", "--checkpoint-every", "0", "--no-progress",
            "--filter", "--filter-penalty", "0.5", "--out", str(out),
        ]
    )  # fmt: skip
    config = json.loads((out / "config.json").read_text())
    assert config["library_settings"]["filter"] == {"penalty": 0.5}
    assert config["robot_steps"] == 512
    with open(out / "progress.csv") as fh:
        progress = list(csv.DictReader(fh))
    with open(out / "shield.csv") as fh:
        shield = list(csv.DictReader(fh))
    assert [int(r["robot_steps"]) for r in progress] == [256, 512]
    assert [int(r["robot_steps"]) for r in shield] == [256, 512]
    assert tuple(shield[0]) == SHIELD_COLUMNS
    for row in shield:
        assert float(row["filter_penalty_mean"]) == pytest.approx(
            0.5 * float(row["correction_sq_mean"]), rel=1e-3, abs=1e-6
        )
    assert (out / "model.zip").exists()


def test_batched_builders_match_one_by_one_and_fall_back_without_a_compiler(monkeypatch):
    """The lane-parallel QP builders (``nmpc_expert.filter_batch``) give the same filtered
    commands as each filter's own ``act`` (1e-9, random proposals, 8 steps); without a C++
    compiler the shield warns and filters one robot after another, before any filter
    moves."""
    from nmpc_expert.filter_batch import BatchedFilterStep

    envs = [_env(action_mode="torque") for _ in range(3)]
    batched, single = Shield(envs[0]), Shield(envs[1], batched=False)

    def no_compiler(self, funcs):
        raise RuntimeError("the batched CPU backend needs a C++ compiler")

    monkeypatch.setattr(BatchedFilterStep, "_function", no_compiler)
    fallback = Shield(envs[2])
    rng = np.random.default_rng(1)
    for env in envs:
        env.reset(seed=5)
    for t in range(8):
        actions = rng.uniform(-1, 1, (K, N, 8))
        if t == 0:
            with pytest.warns(UserWarning, match="one by one"):
                envs[2].step(actions)
        else:
            envs[2].step(actions)
        envs[0].step(actions)
        envs[1].step(actions)
        np.testing.assert_allclose(batched.safe, single.safe, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fallback.safe, single.safe, rtol=0, atol=1e-9)
        assert np.any(np.abs(single.safe - single.proposal) > 1e-3)  # it did correct
