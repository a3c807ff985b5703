"""The one closed-loop episode driver: one policy per agent in, the episode's metrics out.

    episode = play(env, factory, seed=3, on_step=record)
    episode.metrics            # the env's metrics, ``policy_time_ms_*`` added here

Every caller that plays a policy on the environment plays it here, so an episode is the
same episode everywhere and the decision time is measured in one place: around each
agent's ``act``, summarized as ``policy_time_ms_median``, ``_p95`` and ``_max`` over
decisions (NaN without a decision).

Callers attach what they need without another loop:

* ``on_reset(env, obs)`` after the reset, before the policies are built;
* ``execute(index, policy, obs, action)`` right after agent ``index``'s decision: returns
  the action actually applied (DAgger's mixing, exploration noise) and may read the
  policy's ``stats`` of that decision;
* ``on_step(step)`` after each ``env.step``: trajectories, frames, dataset records;
* ``replay=PATH``: the episode's 3D replay page written there (``uvms_env.replay``).

``play_team`` plays a team policy (``uvms_env.team_policy``) through the same loop; its
decision time is per team decision. Each driver refuses the other's kind of factory.

Under an acoustic channel a policy that does not declare ``reads_messages = True`` plays
silent through ``SilentPolicy`` (docs/channel.md, "Policies, evaluation and training").

Only the public env API is used (``reset(seed=)``, ``step``, ``agents``,
``possible_agents``, ``scenario``, the last infos (``uvms_env.env.infos``), and ``comm``
and ``observation_structure`` under a channel).
May import: numpy, ``uvms_env.policy``, ``uvms_env.team_policy``, ``uvms_env.robot.channel``,
``uvms_env.env.infos`` and (when a replay is asked for) ``uvms_env.replay``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.env.infos import EPISODE_END_NAMES, episode_metrics
from uvms_env.policy import AgentSpec, Policy, PolicyFactory
from uvms_env.robot.channel import ChannelSettings, silent
from uvms_env.team_policy import (
    TeamPolicy,
    TeamPolicyFactory,
    check_team_actions,
    is_team_policy,
)

Execute = Callable[[int, Policy, np.ndarray, np.ndarray], np.ndarray]
TIMING = ("median", "p95", "max")  # ``policy_time_ms_<key>`` of an episode's metrics
TEAM = "team"  # the key of a team policy in ``Episode.policies`` and ``Step.policies``


@dataclass(frozen=True)
class Step:
    """One control period as ``on_step`` sees it (``index`` counts from 0)."""

    index: int
    env: Any
    policies: Mapping[str, Policy | TeamPolicy]  # a team policy under ``TEAM``
    actions: dict[str, np.ndarray]  # applied (after ``execute``)
    decision_ms: np.ndarray  # (N,) each agent's ``act`` time; (1,) a team decision's
    observations: dict[str, np.ndarray]  # after the step
    rewards: dict[str, float]
    terminations: dict[str, bool]
    truncations: dict[str, bool]
    infos: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class Episode:
    """A played episode: the env's end metrics (the summed shared reward among them,
    ``return``) with ``policy_time_ms_*`` added, how it ended (``EPISODE_END_NAMES``) and
    each decision's time (steps, N) in ms."""

    metrics: dict[str, Any]
    end: str | None
    decision_ms: np.ndarray
    policies: dict[str, Policy | TeamPolicy]

    @property
    def steps(self) -> int:
        return len(self.decision_ms)


class SilentPolicy:
    """A policy of the silent team under an acoustic channel: it sees its observation
    without the inbox (the first ``size`` numbers) and its 8-number actions go out with a
    silent message part (send flag -1). Actions of the channel's full size pass as they are."""

    def __init__(self, policy: Policy, comm: ChannelSettings, size: int) -> None:
        self.policy, self.comm, self.size = policy, comm, size

    @property
    def stats(self) -> dict[str, Any]:
        return self.policy.stats

    def reset(self) -> None:
        self.policy.reset()

    def act(self, obs: np.ndarray) -> np.ndarray:
        a = np.asarray(self.policy.act(obs[: self.size]), dtype=np.float32)
        return silent(a, self.comm) if a.shape == (NU,) else a

    def executed(self, action: np.ndarray) -> None:
        if hasattr(self.policy, "executed"):
            self.policy.executed(np.asarray(action)[:NU])


def build_policies(env: Any, factory: PolicyFactory) -> dict[str, Policy]:
    """One policy per agent of ``env``'s current scenario, each built from its own
    ``AgentSpec`` (with the channel's settings under ``comm``) and reset; a team policy in
    their place is a TypeError. Under a channel a policy that does not read messages plays
    silent (``SilentPolicy``)."""
    comm = getattr(env, "comm", None)
    policies = {}
    for i, agent in enumerate(env.possible_agents):
        policy = factory(AgentSpec.from_scenario(env.scenario, i, comm))
        if is_team_policy(policy):
            raise TypeError(
                f"the per-robot factory built a team policy ({type(policy).__name__}), "
                "which acts for the whole team from the global state: wrap its builder in "
                "uvms_env.team_policy.TeamPolicyFactory and play it with play_team"
            )
        if comm is not None and not getattr(policy, "reads_messages", False):
            policy = SilentPolicy(policy, comm, env.observation_structure["messages"].start)
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
    episode's replay page. Exceptions of a policy or a hook propagate. A team policy
    factory (``uvms_env.team_policy``) is refused: it plays with ``play_team``."""
    if isinstance(factory, TeamPolicyFactory):
        raise TypeError(
            f"{factory.name} is a team policy factory (one controller for the whole team, "
            "from the global state); play it with uvms_env.episode.play_team"
        )

    def start(env: Any) -> tuple[dict[str, Any], Callable[..., Any]]:
        policies = build_policies(env, factory)
        agents = list(env.agents)

        def decide(obs: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray]:
            actions, ms = {}, np.zeros(len(agents))
            for i, agent in enumerate(agents):
                begin = time.perf_counter()
                policy = policies[agent]
                action = policy.act(obs[agent])
                ms[i] = (time.perf_counter() - begin) * 1e3
                actions[agent] = (
                    action if execute is None else execute(i, policy, obs[agent], action)
                )
            return actions, ms

        return policies, decide

    return _episode(env, seed, start, on_step, on_reset, replay)


def play_team(
    env: Any,
    factory: TeamPolicyFactory,
    seed: int | None = None,
    on_step: Callable[[Step], None] | None = None,
    on_reset: Callable[[Any, dict[str, np.ndarray]], None] | None = None,
    replay: str | Path | None = None,
) -> Episode:
    """``play`` for a team policy (``uvms_env.team_policy``): built once per episode from
    the env's scenario after the reset, it decides for every agent from ``env.state()``.
    Decision times are per team decision: ``decision_ms`` is (steps, 1) and
    ``policy_time_ms`` summarizes them; ``policies`` (in the episode and each ``Step``)
    holds the team policy under the key ``TEAM``."""
    if not isinstance(factory, TeamPolicyFactory):
        raise TypeError(
            f"play_team needs a uvms_env.team_policy.TeamPolicyFactory, got "
            f"{type(factory).__name__}: a per-robot factory (AgentSpec -> Policy) plays "
            "with uvms_env.episode.play"
        )

    def start(env: Any) -> tuple[dict[str, Any], Callable[..., Any]]:
        team = factory(env.scenario)
        comm = getattr(env, "comm", None)
        team.reset()
        agents = list(env.agents)

        def decide(obs: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray]:
            begin = time.perf_counter()
            actions = team.act(env.state())
            ms = np.array([(time.perf_counter() - begin) * 1e3])
            a = check_team_actions(actions, len(agents))
            if comm is not None:  # full information already: it sends nothing
                a = silent(a, comm)
            return {agent: a[i] for i, agent in enumerate(agents)}, ms

        return {TEAM: team}, decide

    return _episode(env, seed, start, on_step, on_reset, replay)


def _episode(
    env: Any,
    seed: int | None,
    start: Callable[[Any], tuple[dict[str, Any], Callable[..., Any]]],
    on_step: Callable[[Step], None] | None,
    on_reset: Callable[[Any, dict[str, np.ndarray]], None] | None,
    replay: str | Path | None,
) -> Episode:
    """The loop both drivers share: reset, ``start(env)`` -> (policies, decide), then
    ``decide(obs) -> (actions, decision times)`` and ``env.step`` until the episode ends."""
    obs, _ = env.reset(seed=seed)
    if on_reset is not None:
        on_reset(env, obs)
    recorder = None
    if replay is not None:
        from uvms_env.replay import ReplayRecorder

        recorder = ReplayRecorder(env)
    policies, decide = start(env)
    if not env.agents:
        raise RuntimeError("the environment has no agent after reset")
    times: list[np.ndarray] = []
    metrics: dict[str, Any] = {}
    end = None
    while env.agents:
        actions, ms = decide(obs)
        times.append(ms)
        obs, rewards, terms, truncs, infos = env.step(actions)
        if recorder is not None:
            recorder.record(infos)
        if on_step is not None:
            on_step(
                Step(len(times) - 1, env, policies, actions, ms, obs, rewards, terms, truncs, infos)
            )
        if env.agents:
            continue
        first = next(iter(infos.values()), {})
        ended = episode_metrics(first)
        if ended is not None:
            metrics, end = ended, EPISODE_END_NAMES[int(first["episode_end"])]
    if recorder is not None:
        recorder.write(replay)
    width = len(times[0]) if times else 1
    decision_ms = np.array(times).reshape(-1, width)
    timing = decision_time_summary(decision_ms)
    for key in TIMING:
        metrics[f"policy_time_ms_{key}"] = timing[key] if timing else float("nan")
    return Episode(metrics, end, decision_ms, policies)
