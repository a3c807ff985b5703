"""Decision time of a cloned policy against the NMPC expert's (one core, one process).

    python benchmarks/cloned_decision.py [--policy dagger:pretrained] [--scenario paper]
                                         [--steps 400] [--seed 0]

Each policy drives its own episode of the scenario (same seed) for ``--steps`` periods
or until the episode ends, and every ``act`` call is timed with the environment stepping
in between, as in ``baselines.evaluate`` (so the caches are as warm or cold as in a
real loop; timing the clone between two expert solves instead measured it 3x slower,
the expert's working set evicting the clone's). Prints median and p95 per policy and
the ratio of the medians.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.policies import PolicySource
from uvms_env.policy import AgentSpec


def measure(policy: str, scenario: str, steps: int, seed: int) -> np.ndarray:
    """Decision times (ms) of ``policy`` driving every robot in closed loop."""
    kwargs = {"n_agents": 2} if scenario == "random" else {}
    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **kwargs)
    obs, _ = env.reset(seed=seed)
    factory = PolicySource.parse(policy).factory(seed)
    policies = [factory(AgentSpec.from_scenario(env.scenario, i)) for i in range(len(env.agents))]
    for p in policies:
        p.reset()
    times: list[float] = []
    for _ in range(steps):
        if not env.agents:
            break
        actions = {}
        for i, agent in enumerate(env.agents):
            start = time.perf_counter()
            actions[agent] = policies[i].act(obs[agent])
            times.append(time.perf_counter() - start)
        obs, *_ = env.step(actions)
    return np.asarray(times) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="dagger:pretrained")
    ap.add_argument("--scenario", default="paper", choices=["paper", "random"])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    times = {p: measure(p, args.scenario, args.steps, args.seed) for p in ("nmpc", args.policy)}
    for name, t in times.items():
        print(f"{name:>28}: median {np.median(t):.4f} ms, p95 {np.percentile(t, 95):.4f} ms "
              f"({t.size} decisions)")  # fmt: skip
    ratio = np.median(times["nmpc"]) / np.median(times[args.policy])
    print(f"expert / clone median: {ratio:.0f}x")


if __name__ == "__main__":
    main()
