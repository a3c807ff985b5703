"""Roll out episodes where an expert labels every visited observation.

The executed action of each robot is the expert's with probability ``beta`` and the
learner's otherwise (``beta = 1``: plain demonstrations; ``beta < 1``: DAgger). The
expert runs on every step either way, so a stateful expert (the NMPC warm-starts from
its previous plan) sees the same observation stream as if it were in control, and its
label is what it would do in the visited state.
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
) -> tuple[list[AgentStream], list[dict]]:
    """Per-robot streams (obs, expert label, reward, ...) and each episode's end metrics."""
    rng = np.random.default_rng(seed)
    streams: list[AgentStream] = []
    metrics: list[dict] = []
    for ep in tqdm(range(episodes), desc="rollouts", disable=not progress, unit="ep"):
        ep_seed = seed + ep
        env = env_factory(ep_seed)
        obs, _ = env.reset(seed=ep_seed)
        agents = list(env.possible_agents)
        specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(len(agents))]
        experts: list[Policy] = [expert(s) for s in specs]
        learners: list[Policy] | None = [learner(s) for s in specs] if learner else None
        for p in experts + (learners or []):
            p.reset()
        ep_streams = {a: AgentStream.start(obs[a], ep_seed) for a in agents}
        end: dict = {}
        while env.agents:
            actions = {}
            for i, a in enumerate(agents):
                start = time.perf_counter()
                label = np.asarray(experts[i].act(obs[a]), dtype=np.float32)
                ep_streams[a].solve_ms.append((time.perf_counter() - start) * 1e3)
                ep_streams[a].actions.append(label)
                executed = label
                if learners is not None and rng.random() >= beta:
                    executed = np.asarray(learners[i].act(obs[a]), dtype=np.float32)
                actions[a] = executed
            obs, rew, term, trunc, infos = env.step(actions)
            for a in agents:
                s = ep_streams[a]
                s.observations.append(np.asarray(obs.get(a, s.observations[-1]), np.float32))
                s.rewards.append(float(rew.get(a, 0.0)))
                s.terminations.append(bool(term.get(a, False)))
                s.truncations.append(bool(trunc.get(a, False)))
                if "metrics" in infos.get(a, {}):
                    end = infos[a]["metrics"]
        env.close()
        streams.extend(ep_streams.values())
        metrics.append(end)
    return streams, metrics
