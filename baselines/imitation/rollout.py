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

import time
from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from baselines.imitation.dataset import AgentStream
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
        ep_seed = seed + ep
        env = env_factory(ep_seed)
        obs, _ = env.reset(seed=ep_seed)
        agents = list(env.possible_agents)
        specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(len(agents))]
        experts: list[Policy] = [expert(s) for s in specs]
        learners: list[Policy] | None = [learner(s) for s in specs] if learner else None
        for p in experts + (learners or []):
            p.reset()
        ring = specs[0].object_ring_radius
        ep_streams = {a: AgentStream.start(obs[a], ep_seed, ring) for a in agents}
        end: dict = {}
        steps = 0
        while env.agents:
            actions = {}
            for i, a in enumerate(agents):
                s = ep_streams[a]
                start = time.perf_counter()
                label = np.asarray(experts[i].act(obs[a]), dtype=np.float32)
                s.solve_ms.append((time.perf_counter() - start) * 1e3)
                stats = getattr(experts[i], "stats", None) or {}
                s.iterations.append(int(stats.get("iterations", 0) or 0))
                s.fallbacks.append(int(stats.get("fallbacks", 0) or 0))
                s.actions.append(label)
                executed = label
                use_learner = learners is not None and rng.random() >= beta
                if use_learner:
                    proposal = np.asarray(learners[i].act(obs[a]), dtype=np.float32)
                    if gate is None or np.max(np.abs(proposal - label)) <= gate:
                        executed = proposal
                    else:
                        use_learner = False
                if noise > 0.0:
                    perturbed = executed + noise * rng.standard_normal(executed.shape)
                    executed = np.clip(perturbed, -1.0, 1.0).astype(np.float32)
                if use_learner or noise > 0.0:
                    # a stateful expert's memory must follow the applied input
                    hook = getattr(experts[i], "executed", None)
                    if hook is not None:
                        hook(executed)
                s.learner_acted.append(bool(use_learner))
                actions[a] = executed
            obs, rew, term, trunc, infos = env.step(actions)
            steps += 1
            for a in agents:
                s = ep_streams[a]
                s.observations.append(np.asarray(obs.get(a, s.observations[-1]), np.float32))
                s.rewards.append(float(rew.get(a, 0.0)))
                s.terminations.append(bool(term.get(a, False)))
                s.truncations.append(bool(trunc.get(a, False)))
                if "metrics" in infos.get(a, {}):
                    end = infos[a]["metrics"]
            if steps % 50 == 0:
                bar.set_postfix(ep=ep, step=steps)
        env.close()
        streams.extend(ep_streams.values())
        metrics.append(end)
        bar.set_postfix(ep=ep, steps=steps, success=bool(end.get("success")))
        bar.update()
    bar.close()
    return streams, metrics
