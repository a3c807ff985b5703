"""Episodes of one per-robot policy played K at a time through the batched environment.

``play_batched(jobs, copies)`` plays jobs of one (policy, case) on a ``VectorEnv`` of
``copies`` environments in float64: each copy starts its job's episode from the job's
seed (``VectorEnv.reset(seed=[...])``, ``restart(ids, seeds)`` when a copy's episode ends
and another job waits), so episode k is the single evaluator's episode k (the float64
batched step equals the single one to ~1e-9, docs/batched.md; over thousands of periods a
marginal closed loop can still end otherwise, docs/evaluation.md). Every robot of every copy
keeps its own policy object, built from the job's seed and the copy's scenario as
``uvms_env.episode.play`` builds it, so memories, priors and random generators are the
single evaluator's; what is shared is the environment's step, one compiled call for all
copies, and no environment is built per episode. Where the robots' policies are saved
networks of one ``batch_key`` (``baselines.loaders.policy_batch``), one ``PolicyBatch``
decides for every robot of every copy in one call per period, with the memory and the
priors each robot's own policy would keep: the same numbers, and each robot-decision's time
is the call's shared over its robots. Should the call raise, each copy is decided alone to
find the episode that fails; the others go on. The rows are ``run_episode``'s, with
``wall_s`` the chunk's time shared over its episodes.

Not batched (``batchable`` says why; the caller plays them one by one): team policies,
the acoustic channel, replays and recorded paths.

May import: the standard library, numpy, ``baselines.evaluation.episode_row``,
``baselines.loaders.sources``, ``baselines.loaders.policy_batch`` and ``uvms_env``.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from baselines.evaluation.episode_row import (
    ERROR_END,
    EpisodeJob,
    checked,
    row_head,
    row_tail,
    within_reach,
)
from baselines.loaders.policy_batch import PolicyBatch, batch_key
from baselines.loaders.sources import PolicySource
from uvms_env.dynamics import NU
from uvms_env.policy import AgentSpec, Policy


def batchable(job: EpisodeJob) -> str | None:
    """Why ``job`` must be played alone (None: it can be batched)."""
    if PolicySource.parse(job.policy).team:
        return "a team policy decides from the global state, one episode at a time"
    if dict(job.overrides).get("comm") is not None:
        return "the acoustic channel's messages are played by the single environment"
    if job.replay is not None or job.record_path:
        return "a replay or a recorded path reads the single environment's state"
    return None


def group_key(job: EpisodeJob) -> tuple[Any, ...]:
    """Jobs with one key share a batched environment (the keywords by their text: a
    value may be a dict, ``randomize``'s)."""
    return (job.policy, job.scenario, repr(job.overrides), job.max_cycles, job.label)


class _Copy:
    """One copy's current episode: its job, its robots' policies and what it has recorded."""

    def __init__(
        self, job: EpisodeJob, policies: list[Policy], scenario: Any | None, cap: int
    ) -> None:
        self.job, self.policies = job, policies
        self.row = row_head(job)
        if scenario is not None:  # None: an episode that never started
            self.row["current_within_reach"] = within_reach(scenario)
        self.row["max_cycles"] = cap
        self.times: list[np.ndarray] = []
        self.filtered = self.interventions = 0
        self.deviation = 0.0
        self.batched = False  # decided by the chunk's PolicyBatch

    def decide(self, obs: np.ndarray) -> np.ndarray:
        ms = np.zeros(len(self.policies))
        actions = np.zeros((len(self.policies), NU), np.float32)
        for i, policy in enumerate(self.policies):
            begin = time.perf_counter()
            actions[i] = policy.act(obs[i])
            ms[i] = (time.perf_counter() - begin) * 1e3
            stats = getattr(policy, "stats", {})
            if "intervened" in stats:
                self.filtered += 1
                self.interventions += bool(stats["intervened"])
                self.deviation += float(stats["intervention"])
        self.times.append(ms)
        return actions

    def finish(
        self, metrics: dict[str, Any] | None, end: str, error: Exception | None = None
    ) -> dict[str, Any]:
        row = self.row
        if metrics is not None:
            row.update(metrics)
        row["episode_end"] = end
        if error is not None:
            row["error"] = f"{type(error).__name__}: {error}"
            row["traceback"] = "".join(traceback.format_exception(error, limit=5))
            row.update(success=False, episode_end=ERROR_END)
        row_tail(row, self.times, (self.filtered, self.interventions, self.deviation))
        row["_path"] = []
        return row


def play_batched(
    jobs: Sequence[EpisodeJob],
    copies: int,
    done: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """The rows of ``jobs`` (one ``group_key``, each ``batchable``), played on up to
    ``copies`` environments at once; ``done(row)`` as each episode ends. Never raises for
    a policy's error: that episode fails with its error, the others go on; an error of the
    environment's step fails every episode then running."""
    from uvms_env.vector import VectorEnv

    jobs = list(jobs)
    if not jobs:
        return []
    if len({group_key(j) for j in jobs}) != 1:
        raise ValueError("play_batched plays jobs of one policy and case (group_key)")
    first = jobs[0]
    kwargs = dict(first.overrides)
    if first.max_cycles is not None:
        kwargs["max_cycles"] = first.max_cycles
    k = min(int(copies), len(jobs))
    source = PolicySource.parse(first.policy)
    start = time.perf_counter()
    rows: list[dict[str, Any]] = []

    def report(row: dict[str, Any]) -> None:
        rows.append(row)
        if done is not None:
            done(row)

    venv = VectorEnv(first.scenario, num_envs=k, dtype="float64", threads=1, **kwargs)
    waiting = iter(jobs)
    running: list[_Copy | None] = [None] * k
    batch: PolicyBatch | None = None

    def begin(job: EpisodeJob, slot: int) -> _Copy | None:
        nonlocal batch
        copy = _begin(job, venv, slot, source, report)
        key = None if copy is None else batch_key(copy.policies)
        if copy is not None and key is not None:
            if batch is None:
                batch = PolicyBatch(copy.policies[0], (k, venv.n))
            if key == batch.key:
                batch.reset(slot)
                copy.batched = True
        return copy

    obs, _ = venv.reset(seed=[j.seed for j in jobs[:k]])
    for slot in range(k):
        running[slot] = begin(next(waiting), slot)
    while True:
        # a free copy (its episode ended, failed or never began) takes the next job;
        # copies with nothing left to play step on zero inputs, unread
        for slot in [s for s, c in enumerate(running) if c is None]:
            job = next(waiting, None)
            if job is None:
                break
            obs[slot] = venv.restart([slot], seeds=[job.seed])[0]
            running[slot] = begin(job, slot)
        if all(c is None for c in running):
            break
        actions = np.zeros((k, venv.n, NU), np.float32)
        together = [s for s, c in enumerate(running) if c is not None and c.batched]
        if together:
            try:
                decide_together(batch, together, obs, actions, running)
            except Exception:  # one call failed: decide each copy alone to find its episode
                for slot in together:
                    try:
                        decide_together(batch, [slot], obs, actions, running)
                    except Exception as exc:  # a failing policy fails its episode only
                        report(running[slot].finish(None, ERROR_END, exc))  # type: ignore[union-attr]
                        running[slot] = None
        for slot, copy in enumerate(running):
            if copy is None or copy.batched:
                continue
            try:
                actions[slot] = copy.decide(obs[slot])
            except Exception as exc:  # a failing policy fails its episode only
                report(copy.finish(None, ERROR_END, exc))
                running[slot] = None
        try:
            obs, _, _, _, infos = venv.step(actions)
        except Exception as exc:  # the step failed: so did every episode not yet ended
            cap = int(venv.max_cycles)
            for copy in [*filter(None, running), *(_Copy(j, [], None, cap) for j in waiting)]:
                report(copy.finish(None, ERROR_END, exc))
            break
        for slot, copy in enumerate(running):
            if copy is not None and infos["metrics"][slot] is not None:
                report(copy.finish(infos["metrics"][slot], infos["episode_end"][slot]))
                running[slot] = None
    share = (time.perf_counter() - start) / len(jobs)
    for row in rows:
        row["wall_s"] = share  # the chunk's compute, spread over its episodes
    return rows


def decide_together(
    batch: PolicyBatch | None,
    slots: list[int],
    obs: np.ndarray,
    actions: np.ndarray,
    running: list[_Copy | None],
) -> None:
    """``actions[slots]`` from one call of ``batch``; each robot's time is the call's
    share."""
    assert batch is not None
    begin = time.perf_counter()
    actions[slots] = batch.act(obs, slots)
    ms = (time.perf_counter() - begin) * 1e3 / (len(slots) * actions.shape[1])
    for slot in slots:
        running[slot].times.append(np.full(actions.shape[1], ms))  # type: ignore[union-attr]


def _begin(
    job: EpisodeJob,
    venv: Any,
    slot: int,
    source: PolicySource,
    report: Callable[[dict[str, Any]], None],
) -> _Copy | None:
    """The copy's robots' policies for ``job`` (None, the episode reported failed, where
    they cannot be built)."""
    scenario = venv.scenarios[slot]
    build = checked(source, job.seed)
    policies: list[Policy] = []
    try:
        for i in range(venv.n):
            policy = build(AgentSpec.from_scenario(scenario, i, None))
            policy.reset()
            policies.append(policy)
    except Exception as exc:
        copy = _Copy(job, [], scenario, int(venv.max_cycles))
        report(copy.finish(None, ERROR_END, exc))
        return None
    return _Copy(job, policies, scenario, int(venv.max_cycles))
