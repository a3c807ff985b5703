"""One episode of one policy, played and turned into one row of ``episodes.csv``.

``run_episode`` plays a job (a policy source, a scenario with its keywords, a seed) through
``uvms_env.episode.play`` (``play_team`` for a team policy), records the decision times,
the safety filter's interventions, the return and the object's path, and never raises: a
policy or environment that fails ends its episode as a failure with the error recorded.
It runs in worker processes (and Ray tasks), so a job is plain picklable data.

May import: the standard library, numpy, ``baselines.loaders.sources`` and ``uvms_env``.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np

from baselines.loaders.sources import PolicySource, check_policy
from uvms_env.episode import decision_time_summary
from uvms_env.policy import AgentSpec, Policy, PolicyFactory

# the ``episode_end`` of an episode that raised (the env's own kinds: EPISODE_ENDS)
ERROR_END = "error"


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to play: a policy source (``baselines.loaders.sources.PolicySource``), a
    scenario with its environment keywords, its index and seed."""

    policy: str
    scenario: str
    index: int
    seed: int
    overrides: tuple[tuple[str, Any], ...]
    max_cycles: int | None
    record_path: bool
    replay: str | None = None  # where to write the episode's 3D replay page
    label: str | None = None  # the rows' scenario (a ``Case``'s label); None: the scenario


def run_episode(job: EpisodeJob) -> dict[str, Any]:
    """Play one episode; never raises (errors become failed episodes)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import uvms_env
    from uvms_env.episode import Step, play, play_team

    row = row_head(job)
    times: list[np.ndarray] = []  # kept here too: a failed episode reports its decisions
    path: list[list[float]] = []
    filtered, interventions, deviation = 0, 0, 0.0  # safety-filter decisions (``+filter``)

    def reached(env: Any, _obs: Any) -> None:
        row["current_within_reach"] = within_reach(env.scenario)
        row["max_cycles"] = int(env.max_cycles)  # the cap a failure's time is counted at

    def record(step: Step) -> None:
        nonlocal filtered, interventions, deviation
        times.append(step.decision_ms)
        for policy in step.policies.values():
            if "intervened" in policy.stats:
                filtered += 1
                interventions += bool(policy.stats["intervened"])
                deviation += float(policy.stats["intervention"])
        if job.record_path:
            path.append(step.env.unwrapped.sim.state.x_O[:3].tolist())

    start = time.perf_counter()
    try:
        kwargs = dict(job.overrides)
        if job.max_cycles is not None:
            kwargs["max_cycles"] = job.max_cycles
        env = uvms_env.parallel_env(scenario=job.scenario, seed=job.seed, **kwargs)
        source = PolicySource.parse(job.policy)
        hooks: dict[str, Any] = {"on_step": record, "on_reset": reached, "replay": job.replay}
        if source.team:  # one decision for the whole team, from the global state
            episode = play_team(env, source.team_factory(job.seed), job.seed, **hooks)
        else:
            episode = play(env, checked(source, job.seed), job.seed, **hooks)
        env.close()
        row.update(episode.metrics)  # flat numbers, the return among them
        row["episode_end"] = episode.end  # success, max_cycles, collision, ...
    except Exception as exc:  # a failing policy must not stop the evaluation
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=5)
        row["success"] = False
        row["episode_end"] = ERROR_END
    row_tail(row, times, (filtered, interventions, deviation))
    row["wall_s"] = time.perf_counter() - start  # the episode's compute, for the tables' cost
    row["_path"] = path
    return row


def row_head(job: EpisodeJob) -> dict[str, Any]:
    """The row's columns known before the episode."""
    return {
        "policy": job.policy,
        # "full": a team policy, the full-information reference, never a decentralized entry
        "information": PolicySource.parse(job.policy).information,
        "scenario": job.label or job.scenario,
        "episode": job.index,
        "seed": job.seed,
        "error": "",
    }


def row_tail(
    row: dict[str, Any], times: list[np.ndarray], filtered: tuple[int, int, float]
) -> None:
    """The row's columns after the episode: a failed one's metrics, the safety filter's
    interventions (``filtered``: decisions filtered, interventions, summed deviation) and
    the decision times (``times``: each step's per-robot ms)."""
    if row["error"]:  # no env metrics: the episode did not end
        row.update(violation_periods=0, clean_success=False, clean_success_tol=False)
        row["return"] = float("nan")
    count, interventions, deviation = filtered
    row["interventions"] = interventions
    row["filtered_decisions"] = count
    row["intervention_rate"] = interventions / count if count else None
    row["intervention_mean"] = deviation / count if count else None
    ms = np.concatenate(times) if times else np.zeros(0)
    timing = decision_time_summary(ms)
    for key in ("median", "p95", "max"):
        row[f"policy_time_ms_{key}"] = timing[key] if timing else float("nan")
    row["_decision_ms"] = ms.tolist()


def checked(source: PolicySource, seed: int) -> PolicyFactory:
    """The source's policies, each checked against the interface as it is built. The
    source's factory is made with the first policy, after the env's reset: a source that
    fails (a missing model) fails an episode whose reach is known."""
    made: list[PolicyFactory] = []

    def build(spec: AgentSpec) -> Policy:
        if not made:
            made.append(source.factory(seed))
        policy = made[0](spec)
        check_policy(policy)
        return policy

    return build


def within_reach(scenario: Any) -> bool:
    """Whether the team can hold against the scenario's current at all
    (``uvms_env.scenarios.reach``); no current is always within reach."""
    from uvms_env.scenarios.reach import reachable

    return reachable(scenario)
