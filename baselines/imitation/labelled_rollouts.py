"""Roll out episodes where an expert labels every visited observation.

The executed action of each robot is the expert's with probability ``beta`` and the
learner's otherwise, drawn independently per robot and per step (``beta = 1``: plain
demonstrations; ``beta < 1``: DAgger). The expert runs on every step either way, so a
stateful expert (the NMPC warm-starts from its previous plan) sees the same observation
stream as if it were in control, and its label is what it would do in the visited state;
an expert with an ``executed(action)`` hook (the NMPC's rate-offset estimator) is told
which action was applied.

``noise > 0`` adds Gaussian noise of that standard deviation to every executed action
(clipped to [-1, 1]; the label stays the expert's clean action): DART (Laskey et al.
2017). The arms react to a torque error of a few hundredths within a few periods, so
clean demonstrations never show the expert's answer to a joint-rate error of the size a
learner makes at once; perturbed ones do, around the expert's own path.

``gate`` (SafeDAgger-style, Zhang & Cho 2017): the learner's action is executed only
when it is within ``gate`` of the expert's label in every component; otherwise the
expert's is. A clone that has left the expert's state distribution spends the rest of a
plain DAgger rollout in fast joint motion against the limits, and the aggregate fills
with those (expert-saturated, hard to fit) states; gating keeps the visited states near
the ones the learner has to master, yet reached by the learner's own small errors.

Every stream also records each robot's memory block (``uvms_env.robot.memory``: the last
command it executed and its disturbance estimate) at each observation, as a policy on
``memory`` features would have built it along that stream. A learner with a memory is
asked for its action every step and told what was executed, so that its memory follows
the stream whoever acted.

``parallel_rollouts`` plays a ``RolloutJob`` (what to play, by names and paths: it
crosses process boundaries) on worker processes, one contiguous block of episodes each;
the streams come back in episode order, the same as one process would give. A job may
draw each episode's team size from a set (``n_agents``, the random family, cycled over
the episodes) and its current and mismatch through the environment's ``randomize``.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from baselines.imitation.dataset import AgentStream
from baselines.imitation.teacher import TeamTeacher
from uvms_env.episode import Step, play
from uvms_env.policy import AgentSpec, Policy, PolicyFactory
from uvms_env.robot.memory import RobotMemory
from uvms_env.team_policy import TeamPolicyFactory

_LABELLING_STREAM = 0xDA66E2  # mixed into each episode's seed: its labelling draws


def rollouts(
    env_factory: Callable[[int], object],
    expert: PolicyFactory | TeamPolicyFactory,
    episodes: int,
    seed: int,
    learner: PolicyFactory | None = None,
    beta: float = 1.0,
    progress: bool = True,
    desc: str = "rollouts",
    noise: float = 0.0,
    gate: float | None = None,
) -> tuple[list[AgentStream], list[dict]]:
    """Per-robot streams (obs, expert label, reward, memory, ...) and each episode's end
    metrics. Episode ``ep`` uses ``env_factory(seed + ep)`` reset with ``seed + ep``; its
    mixing and noise draws come from a generator of its own, keyed by that seed. A team
    ``expert`` (``nmpc:central``) labels each robot with its row of the team's decision
    (``baselines.imitation.teacher``)."""
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta}")
    if not noise >= 0.0:
        raise ValueError(f"noise must be >= 0, got {noise}")
    streams: list[AgentStream] = []
    metrics: list[dict] = []
    bar = tqdm(total=episodes, desc=desc, disable=not progress, unit="ep")
    for ep in range(episodes):
        # each episode's mixing and noise draws: its own stream, keyed by its seed
        rng = np.random.default_rng([seed + ep, _LABELLING_STREAM])
        labelled = _Labelling(seed + ep, rng, learner, beta, noise, gate)

        def record(step: Step, labelled: _Labelling = labelled, ep: int = ep) -> None:
            labelled.record(step)
            if step.index == 0:
                # the episode's env, geometry and policies are built, its first decision
                # compiled: the bar's rate and ETA leave that time out
                bar.unpause()
            if (step.index + 1) % 50 == 0:
                bar.set_postfix(ep=ep, step=step.index + 1)

        env = env_factory(seed + ep)
        labels = TeamTeacher(expert, env) if isinstance(expert, TeamPolicyFactory) else expert
        episode = play(env, labels, seed + ep, labelled.execute, record, labelled.start)
        env.close()
        streams.extend(labelled.streams.values())
        metrics.append(episode.metrics)
        bar.set_postfix(ep=ep, steps=episode.steps, success=bool(episode.metrics.get("success")))
        bar.update()
    bar.close()
    return streams, metrics


@dataclass
class _Labelling:
    """One episode's per-robot streams: the expert labels, the executed action is drawn
    from the expert's and the learner's (module docstring)."""

    ep_seed: int
    rng: np.random.Generator
    learner: PolicyFactory | None
    beta: float
    noise: float
    gate: float | None
    streams: dict[str, AgentStream] = field(default_factory=dict)
    stream_list: list[AgentStream] = field(default_factory=list)
    learners: list[Policy] | None = None

    def start(self, env: Any, obs: dict[str, np.ndarray]) -> None:
        agents = env.possible_agents
        specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(len(agents))]
        ring = specs[0].object_key
        self.streams = {a: AgentStream.start(obs[a], self.ep_seed, ring) for a in agents}
        self.stream_list = list(self.streams.values())
        self.memories = [RobotMemory(spec.period, ring) for spec in specs]
        for a, memory in zip(agents, self.memories, strict=True):
            self.streams[a].memory.append(memory.observe(obs[a]))
        if self.learner is not None:
            self.learners = [self.learner(s) for s in specs]
            for p in self.learners:
                p.reset()

    def execute(self, i: int, expert: Policy, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        s = self.stream_list[i]
        label = np.asarray(action, dtype=np.float32)
        stats = getattr(expert, "stats", None) or {}
        s.iterations.append(int(stats.get("iterations", 0) or 0))
        s.fallbacks.append(int(stats.get("fallbacks", 0) or 0))
        s.actions.append(label)
        executed = label
        learner = self.learners[i] if self.learners is not None else None
        # a learner with a memory decides every step, so that its memory follows the stream
        stateful = learner is not None and hasattr(learner, "executed")
        use_learner = learner is not None and self.rng.random() >= self.beta
        proposal = None
        if use_learner or stateful:
            proposal = np.asarray(learner.act(obs), dtype=np.float32)  # type: ignore[union-attr]
        if use_learner:
            assert proposal is not None
            if self.gate is None or np.max(np.abs(proposal - label)) <= self.gate:
                executed = proposal
            else:
                use_learner = False
        if self.noise > 0.0:
            perturbed = executed + self.noise * self.rng.standard_normal(executed.shape)
            executed = np.clip(perturbed, -1.0, 1.0).astype(np.float32)
        if use_learner or self.noise > 0.0:
            # a stateful expert's memory must follow the applied input
            hook = getattr(expert, "executed", None)
            if hook is not None:
                hook(executed)
        if stateful and not (use_learner and self.noise == 0.0):
            learner.executed(executed)  # type: ignore[union-attr]
        self.memories[i].issued(executed)
        s.learner_acted.append(bool(use_learner))
        return executed

    def record(self, step: Step) -> None:
        for i, (a, s) in enumerate(self.streams.items()):
            s.solve_ms.append(float(step.decision_ms[i]))
            s.observations.append(
                np.asarray(step.observations.get(a, s.observations[-1]), np.float32)
            )
            s.memory.append(self.memories[i].observe(s.observations[-1]))
            s.rewards.append(float(step.rewards.get(a, 0.0)))
            s.terminations.append(bool(step.terminations.get(a, False)))
            s.truncations.append(bool(step.truncations.get(a, False)))


@dataclass(frozen=True)
class RolloutJob:
    """What ``parallel_rollouts`` plays, by names and paths (it is pickled to the workers):
    ``scenario`` with environment ``overrides`` (``randomize`` included), each episode's
    team size drawn from ``n_agents`` (random family; cycled: episode e plays
    ``n_agents[e % len]``; empty: the overrides') and its object from ``objects`` (cycled
    over whole rounds of team sizes, so that every size meets every object), episodes
    capped at ``cap`` periods,
    labelled by ``expert`` (an evaluator policy source, a team one included), the ``learner`` a
    clone's ``policy.pt`` (None: demonstrations) with ``beta``, ``noise`` and ``gate`` as
    in ``rollouts``."""

    scenario: str
    overrides: dict[str, Any] = field(default_factory=dict)
    n_agents: tuple[int, ...] = ()
    cap: int | None = None
    expert: str = "nmpc"
    learner: Path | None = None
    beta: float = 1.0
    noise: float = 0.0
    gate: float | None = None
    objects: tuple[str, ...] = ()

    def env(self, seed: int, episode: int) -> Any:
        """The environment of episode ``episode`` (geometry ``seed`` for seeded families)."""
        import uvms_env

        overrides = dict(self.overrides)
        if self.n_agents:
            overrides["n_agents"] = self.n_agents[episode % len(self.n_agents)]
        if self.objects:
            rounds = episode // max(len(self.n_agents), 1)
            overrides["object"] = self.objects[rounds % len(self.objects)]
        env = uvms_env.parallel_env(scenario=self.scenario, seed=seed, **overrides)
        if self.cap:
            env.max_cycles = min(env.max_cycles, self.cap)
        return env


def _play_block(
    job: RolloutJob, first: int, count: int, seed: int, desc: str, progress: bool
) -> tuple[list[AgentStream], list[dict]]:
    """Episodes ``first .. first + count - 1`` of ``job`` (episode e: seed ``seed + e``), in
    this process."""
    from baselines.loaders.clone_policy import ClonedPolicy
    from baselines.loaders.sources import PolicySource

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    source = PolicySource.parse(job.expert)
    expert = (source.team_factory if source.team else source.factory)(seed + first)
    path = job.learner
    learner = None if path is None else lambda spec: ClonedPolicy(spec, path)
    return rollouts(
        lambda s: job.env(s, s - seed),
        expert,
        count,
        seed + first,
        learner,
        job.beta,
        progress,
        desc,
        job.noise,
        job.gate,
    )


def parallel_rollouts(
    job: RolloutJob,
    episodes: int,
    seed: int,
    workers: int = 1,
    progress: bool = True,
    desc: str = "rollouts",
) -> tuple[list[AgentStream], list[dict]]:
    """``episodes`` episodes of ``job`` (episode e: seed ``seed + e``) on ``workers``
    processes (1: this one), each a contiguous block; streams and metrics in episode
    order. The labelling draws of a block come from its own first seed, so a block's
    episodes do not depend on how many workers share the job."""
    workers = max(1, min(int(workers), episodes))
    if workers == 1:
        return _play_block(job, 0, episodes, seed, desc, progress)
    # one period of each team size first, in this process: the compiled models land in
    # the disk cache before the workers would race to build them
    warm = dataclasses.replace(job, cap=1)
    for e in range(min(episodes, max(1, len(job.n_agents)))):
        _play_block(warm, e, 1, seed, desc, progress=False)
    bounds = np.linspace(0, episodes, workers + 1).astype(int)
    blocks = [
        (job, int(a), int(b - a), seed, f"{desc} [{w}]", progress)
        for w, (a, b) in enumerate(itertools.pairwise(bounds))
        if b > a
    ]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        done = list(pool.map(_play_block, *zip(*blocks, strict=True)))
    return [s for new, _ in done for s in new], [m for _, ms in done for m in ms]
