"""The one closed-loop episode driver: one policy per agent in, the episode's metrics out.

    episode = play(env, factory, seed=3, on_step=record)
    episode.metrics            # the env's metrics, ``policy_time_ms`` filled here

Every caller that plays a policy on the environment (the evaluator, the expert's main job,
the imitation rollouts, the analysis scripts) plays it here, so an episode is the same
episode everywhere and the decision time is measured in one place: around each agent's
``act``, summarized as ``policy_time_ms`` (median, p95, max over agent decisions).

Callers attach what they need without another loop:

* ``on_reset(env, obs)`` after the reset, before the policies are built;
* ``execute(index, policy, obs, action)`` right after agent ``index``'s decision: returns
  the action actually applied (DAgger's mixing, exploration noise) and may read the
  policy's ``stats`` of that decision;
* ``on_step(step)`` after each ``env.step``: trajectories, frames, dataset records;
* ``replay=PATH``: the episode's 3D replay page written there (``uvms_env.replay``).

Only the public env API is used (``reset(seed=)``, ``step``, ``agents``,
``possible_agents``, ``scenario``, ``infos[agent]["metrics"]``).
May import: numpy, ``uvms_env.policy`` and (when a replay is asked for) ``uvms_env.replay``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.policy import AgentSpec, Policy, PolicyFactory

Execute = Callable[[int, Policy, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Step:
    """One control period as ``on_step`` sees it (``index`` counts from 0)."""

    index: int
    env: Any
    policies: Mapping[str, Policy]
    actions: dict[str, np.ndarray]  # applied (after ``execute``)
    decision_ms: np.ndarray  # (N,) each agent's ``act`` time
    observations: dict[str, np.ndarray]  # after the step
    rewards: dict[str, float]
    terminations: dict[str, bool]
    truncations: dict[str, bool]
    infos: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class Episode:
    """A played episode: the env's end metrics with ``policy_time_ms`` filled, how it
    ended, the summed shared reward and each decision's time (steps, N) in ms."""

    metrics: dict[str, Any]
    end: str | None
    total_reward: float
    decision_ms: np.ndarray
    policies: dict[str, Policy]

    @property
    def steps(self) -> int:
        return len(self.decision_ms)


def build_policies(env: Any, factory: PolicyFactory) -> dict[str, Policy]:
    """One policy per agent of ``env``'s current scenario, each built from its own
    ``AgentSpec`` and reset."""
    policies = {}
    for i, agent in enumerate(env.possible_agents):
        policy = factory(AgentSpec.from_scenario(env.scenario, i))
        policy.reset()
        policies[agent] = policy
    return policies


def decision_time_summary(decision_ms: np.ndarray) -> dict[str, float] | None:
    """Median, p95 and max of the decision times (ms); None when there were none."""
    ms = np.asarray(decision_ms, dtype=float).ravel()
    if not len(ms):
        return None
    return {
        "median": float(np.median(ms)),
        "p95": float(np.quantile(ms, 0.95)),
        "max": float(ms.max()),
    }


def play(
    env: Any,
    factory: PolicyFactory,
    seed: int | None = None,
    execute: Execute | None = None,
    on_step: Callable[[Step], None] | None = None,
    on_reset: Callable[[Any, dict[str, np.ndarray]], None] | None = None,
    replay: str | Path | None = None,
) -> Episode:
    """Reset ``env`` with ``seed``, build a policy per agent with ``factory`` (after the
    reset: a random scenario's geometry is drawn there) and play until the episode ends.
    ``on_reset(env, obs)`` sees the first observations; ``replay``: where to write the
    episode's replay page. Exceptions of a policy or a hook propagate."""
    obs, _ = env.reset(seed=seed)
    if on_reset is not None:
        on_reset(env, obs)
    recorder = None
    if replay is not None:
        from uvms_env.replay import ReplayRecorder

        recorder = ReplayRecorder(env)
    policies = build_policies(env, factory)
    agents = list(env.agents)
    if not agents:
        raise RuntimeError("the environment has no agent after reset")
    times: list[np.ndarray] = []
    total_reward = 0.0
    metrics: dict[str, Any] = {}
    end = None
    while env.agents:
        actions, ms = {}, np.zeros(len(agents))
        for i, agent in enumerate(agents):
            start = time.perf_counter()
            policy = policies[agent]
            action = policy.act(obs[agent])
            ms[i] = (time.perf_counter() - start) * 1e3
            actions[agent] = action if execute is None else execute(i, policy, obs[agent], action)
        times.append(ms)
        obs, rewards, terms, truncs, infos = env.step(actions)
        if recorder is not None:
            recorder.record(infos)
        # the reward is the team's, shared by every agent
        total_reward += float(next(iter(rewards.values()))) if rewards else 0.0
        if on_step is not None:
            on_step(
                Step(len(times) - 1, env, policies, actions, ms, obs, rewards, terms, truncs, infos)
            )
        for info in infos.values():
            if "metrics" in info:
                metrics, end = dict(info["metrics"]), info.get("episode_end")
    if recorder is not None:
        recorder.write(replay)
    decision_ms = np.array(times).reshape(-1, len(agents))
    metrics["policy_time_ms"] = decision_time_summary(decision_ms)
    return Episode(metrics, end, total_reward, decision_ms, policies)
