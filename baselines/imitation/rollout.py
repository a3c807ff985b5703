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
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm import tqdm

from baselines.imitation.dataset import AgentStream
from uvms_env.episode import Step, play
from uvms_env.policy import AgentSpec, Policy, PolicyFactory


def rollouts(
    env_factory: Callable[[int], object],
    expert: PolicyFactory,
    episodes: int,
    seed: int,
    learner: PolicyFactory | None = None,
    beta: float = 1.0,
    progress: bool = True,
    desc: str = "rollouts",
    noise: float = 0.0,
    gate: float | None = None,
) -> tuple[list[AgentStream], list[dict]]:
    """Per-robot streams (obs, expert label, reward, ...) and each episode's end metrics.
    Episode ``ep`` uses ``env_factory(seed + ep)`` reset with ``seed + ep``."""
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta}")
    if not noise >= 0.0:
        raise ValueError(f"noise must be >= 0, got {noise}")
    rng = np.random.default_rng(seed)
    streams: list[AgentStream] = []
    metrics: list[dict] = []
    bar = tqdm(total=episodes, desc=desc, disable=not progress, unit="ep")
    for ep in range(episodes):
        labelled = _Labelling(seed + ep, rng, learner, beta, noise, gate)

        def record(step: Step, labelled: _Labelling = labelled, ep: int = ep) -> None:
            labelled.record(step)
            if (step.index + 1) % 50 == 0:
                bar.set_postfix(ep=ep, step=step.index + 1)

        env = env_factory(seed + ep)
        episode = play(env, expert, seed + ep, labelled.execute, record, labelled.start)
        env.close()
        streams.extend(labelled.streams.values())
        metrics.append(episode.metrics)
        bar.set_postfix(ep=ep, steps=episode.steps, success=bool(episode.metrics.get("success")))
        bar.update()
    bar.close()
    return streams, metrics


class _Labelling:
    """One episode's per-robot streams: the expert labels, the executed action is drawn
    from the expert's and the learner's (module docstring)."""

    def __init__(
        self,
        ep_seed: int,
        rng: np.random.Generator,
        learner: PolicyFactory | None,
        beta: float,
        noise: float,
        gate: float | None,
    ) -> None:
        self.ep_seed, self.rng, self.learner = ep_seed, rng, learner
        self.beta, self.noise, self.gate = beta, noise, gate
        self.streams: dict[str, AgentStream] = {}
        self.stream_list: list[AgentStream] = []
        self.learners: list[Policy] | None = None

    def start(self, env: Any, obs: dict[str, np.ndarray]) -> None:
        agents = env.possible_agents
        specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(len(agents))]
        ring = specs[0].object_ring_radius
        self.streams = {a: AgentStream.start(obs[a], self.ep_seed, ring) for a in agents}
        self.stream_list = list(self.streams.values())
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
        use_learner = self.learners is not None and self.rng.random() >= self.beta
        if use_learner:
            proposal = np.asarray(self.learners[i].act(obs), dtype=np.float32)
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
        s.learner_acted.append(bool(use_learner))
        return executed

    def record(self, step: Step) -> None:
        for i, (a, s) in enumerate(self.streams.items()):
            s.solve_ms.append(float(step.decision_ms[i]))
            s.observations.append(
                np.asarray(step.observations.get(a, s.observations[-1]), np.float32)
            )
            s.rewards.append(float(step.rewards.get(a, 0.0)))
            s.terminations.append(bool(step.terminations.get(a, False)))
            s.truncations.append(bool(step.truncations.get(a, False)))
