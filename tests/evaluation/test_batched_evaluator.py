"""The batched evaluator (``baselines.evaluation.batched``) against the one-by-one one: the
same episodes, the same rows.

Tolerance: the float64 batched step equals the single env's to ~1e-9 per step; over 40
closed-loop periods the rows' numbers agree to 1e-6 relative (measured: 2e-10 over 80
periods, 3e-7 over 300 of a random N = 2 team under the prior).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from baselines.evaluation.batched import batchable, play_batched
from baselines.evaluation.episode_row import EpisodeJob, run_episode
from baselines.evaluation.runner import case_episode_seed, evaluate
from uvms_env.vector import VectorEnv

CONDITIONS = (("current", "mild"), ("mismatch", 0.1), ("n_agents", 2))
CYCLES = 40
UNTIMED = ("wall_s", "traceback")


def jobs(policy: str, count: int, scenario: str = "random") -> list[EpisodeJob]:
    seeds = [case_episode_seed(7, scenario, k) for k in range(count)]
    return [
        EpisodeJob(policy, scenario, k, s, CONDITIONS, CYCLES, False) for k, s in enumerate(seeds)
    ]


def assert_same_rows(single: list[dict], batched: list[dict]) -> None:
    assert [r["episode"] for r in single] == [r["episode"] for r in batched]
    for a, b in zip(single, batched, strict=True):
        keys = {k for k in a if not k.startswith(("_", "policy_time")) and k not in UNTIMED}
        assert keys == {k for k in b if not k.startswith(("_", "policy_time")) and k not in UNTIMED}
        for key in keys:
            va, vb = a[key], b[key]
            if isinstance(va, float) and isinstance(vb, float):
                if math.isnan(va):
                    assert math.isnan(vb), key
                else:
                    assert vb == pytest.approx(va, rel=1e-6, abs=1e-9), key
            else:
                assert va == vb, key
        assert len(a["_decision_ms"]) == len(b["_decision_ms"])  # one time per robot-decision


@pytest.mark.parametrize("policy", ["prior", "random"])
def test_batched_rows_equal_the_single_rows(policy: str) -> None:
    # 4 episodes on 3 copies: the copy whose episode ends first restarts on the fourth seed
    todo = jobs(policy, 4)
    single = [run_episode(j) for j in todo]
    batched = sorted(play_batched(todo, 3), key=lambda r: r["episode"])
    assert all(not r["error"] for r in single + batched)
    assert_same_rows(single, batched)


def test_episodes_that_draw_their_conditions_batch_as_they_play_alone() -> None:
    # a training run's evaluations: each episode draws its current and mismatch
    draws = (("n_agents", 2), ("randomize", {"current": ["none", "mild"], "mismatch": [0, 0.1]}))
    todo = [
        EpisodeJob("prior", "random", k, case_episode_seed(3, "random", k), draws, CYCLES, False)
        for k in range(3)
    ]
    single = [run_episode(j) for j in todo]
    batched = sorted(play_batched(todo, 2), key=lambda r: r["episode"])
    assert all(not r["error"] for r in single + batched)
    assert_same_rows(single, batched)


def test_the_runner_batches_without_changing_its_rows() -> None:
    cases = ["short"]
    one = evaluate(["prior", "zero"], cases, 3, 11, 1, dict(CONDITIONS[:2]), CYCLES, False)
    many = evaluate(
        ["prior", "zero"], cases, 3, 11, 1, dict(CONDITIONS[:2]), CYCLES, False, batch=2
    )
    assert_same_rows(one, many)


@pytest.mark.parametrize("policy", ["ppo:scratch", "dagger:mix"])
def test_saved_networks_decide_every_robot_in_one_call_with_the_single_rows(
    policy: str, monkeypatch
) -> None:
    # memory-mode networks: the batch keeps every robot's memory as its own policy would
    from baselines.evaluation import batched

    def alone(self, obs):
        raise AssertionError("a saved network's robot decided alone")

    todo = jobs(policy, 3)
    single = [run_episode(j) for j in todo]
    monkeypatch.setattr(batched._Copy, "decide", alone)
    rows = sorted(play_batched(todo, 2), key=lambda r: r["episode"])
    assert all(not r["error"] for r in single + rows)
    assert_same_rows(single, rows)


def test_a_failing_policy_fails_its_episodes_not_the_others(monkeypatch) -> None:
    # the batch's call fails inside the decision, after the memory's estimate: the copies
    # decided again one by one play on as if nothing had happened
    from baselines.loaders.policy_batch import PolicyBatch

    calls = {"n": 0}
    real = PolicyBatch._decide

    def flaky(self, obs, raw, ids, block):  # copy 1's decisions fail from its fifth on
        if 1 in ids:
            calls["n"] += 1
            if calls["n"] >= 5:
                raise RuntimeError("solver failed")
        return real(self, obs, raw, ids, block)

    todo = jobs("ppo:scratch", 3)
    monkeypatch.setattr(PolicyBatch, "_decide", flaky)
    rows = sorted(play_batched(todo, 3), key=lambda r: r["episode"])
    assert [bool(r["error"]) for r in rows] == [False, True, False]
    assert rows[1]["error"] == "RuntimeError: solver failed" and not rows[1]["success"]
    assert rows[1]["episode_end"] == "error" and math.isnan(rows[1]["return"])
    assert len(rows[1]["_decision_ms"]) == 4 * 2  # its four decisions, two robots
    monkeypatch.setattr(PolicyBatch, "_decide", real)
    assert_same_rows([run_episode(todo[0]), run_episode(todo[2])], [rows[0], rows[2]])


def test_a_failing_robot_by_robot_policy_fails_its_episode_only(monkeypatch) -> None:
    from baselines.evaluation import batched

    calls = {"n": 0}
    real = batched._Copy.decide

    def flaky(self, obs):  # the second episode's policy raises on its fifth decision
        if self.job.index == 1:
            calls["n"] += 1
            if calls["n"] == 5:
                raise RuntimeError("solver failed")
        return real(self, obs)

    monkeypatch.setattr(batched._Copy, "decide", flaky)
    rows = sorted(play_batched(jobs("random", 3), 3), key=lambda r: r["episode"])
    assert [bool(r["error"]) for r in rows] == [False, True, False]
    assert rows[1]["error"] == "RuntimeError: solver failed" and not rows[1]["success"]


def test_a_copy_freed_by_a_failure_plays_the_waiting_episodes(monkeypatch) -> None:
    from baselines.loaders.policy_batch import PolicyBatch

    episodes = {"n": 0}
    real_reset, real_act = PolicyBatch.reset, PolicyBatch.act

    def counted(self, slot):
        episodes["n"] += 1
        real_reset(self, slot)

    def failing_first(self, obs, slots):  # the first episode's policy raises at once
        if episodes["n"] == 1:
            raise RuntimeError("no solution")
        return real_act(self, obs, slots)

    monkeypatch.setattr(PolicyBatch, "reset", counted)
    monkeypatch.setattr(PolicyBatch, "act", failing_first)
    todo = jobs("prior", 3)
    rows = sorted(play_batched(todo, 1), key=lambda r: r["episode"])  # one copy for all
    assert [r["episode"] for r in rows] == [0, 1, 2]
    assert rows[0]["error"] == "RuntimeError: no solution"
    monkeypatch.setattr(PolicyBatch, "act", real_act)
    assert_same_rows([run_episode(j) for j in todo[1:]], rows[1:])


def test_what_plays_one_by_one_says_why() -> None:
    job = jobs("prior", 1)[0]
    assert batchable(job) is None
    assert "team policy" in batchable(EpisodeJob("nmpc:central", "random", 0, 1, (), 5, False))
    assert "channel" in batchable(
        EpisodeJob("prior", "random", 0, 1, (("comm", "ideal"),), 5, False)
    )
    assert "replay" in batchable(EpisodeJob("prior", "paper", 0, 1, (), 5, True))


def test_restart_with_seeds_starts_the_single_envs_episode() -> None:
    venv = VectorEnv("random", num_envs=2, n_agents=2)
    venv.reset(seed=[5, 6])
    venv.step(np.zeros((2, 2, 8), np.float32))
    again = venv.restart([1], seeds=[9])
    fresh = VectorEnv("random", num_envs=1, n_agents=2)
    first, _ = fresh.reset(seed=[9])
    np.testing.assert_array_equal(again[0], first[0])
    with pytest.raises(ValueError, match="one seed per id"):
        venv.restart([0, 1], seeds=[3])


def test_restart_with_seeds_follows_the_geometry_pool_as_reset_does() -> None:
    venv = VectorEnv("random", num_envs=2, n_agents=2, geometry_pool=3)
    first, infos = venv.reset(seed=[4, 5])  # pool seeds 4 % 3 and 5 % 3
    venv.step(np.zeros((2, 2, 8), np.float32))
    again = venv.restart([1], seeds=[5])
    np.testing.assert_array_equal(again[0], first[1])
    assert infos["episode_seed"].tolist() == [1, 2]
