"""How far a robot's best local prediction is from its own joint rates, per team and object.

    python scripts/innovation_probe.py --object bar --n-agents 2 4 6 --episodes 2 \\
        --max-cycles 800 --seed 202

Plays the evaluator's episodes (``baselines.evaluation.runner.case_episode_seed``: the same
seeds as ``python -m baselines.ladder --seed 202`` with the same team size, object, mild
current and mismatch 0.1) with the distributed expert and reads, each period and robot, its
one-step innovation on the joint rates (``innovation_joint_max``: what its prediction,
the disturbance observer's estimate included, missed of the rates it then measured), as a
fraction of the joint-speed limit. A robot plans its joints within ``angular_backoff`` of
the limit less its margin; an error larger than the room it leaves breaks the limit
whatever it planned. Printed per case and per lever arm |l_i|: the median, the 95th and
99th percentiles and the share of periods above 0.5 (the planned bound at the default
``angular_backoff``).

An analysis script, not part of the installed packages.
May import: numpy, ``uvms_env`` and ``baselines``.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
from tqdm import tqdm

import uvms_env
from baselines.evaluation.runner import case_episode_seed
from baselines.loaders.sources import PolicySource
from uvms_env.episode import Step, play

ROOM = 0.5  # the planned joint-speed bound, a fraction of the limit (angular_backoff)


def innovations(policy: str, seed: int, overrides: dict) -> dict[float, list[float]]:
    """Per lever arm (rounded to 0.1 m): every period's joint innovation of its robots."""
    env = uvms_env.parallel_env(scenario="random", seed=seed, **overrides)
    levers = {
        agent: round(float(np.linalg.norm(offset)), 1)
        for agent, offset in zip(env.possible_agents, env.scenario.grasp_offsets, strict=True)
    }
    found: dict[float, list[float]] = defaultdict(list)

    def on_step(step: Step) -> None:
        if step.index == 0:  # no measurement before the first decision
            return
        for agent, policy_of in step.policies.items():
            found[levers[agent]].append(float(policy_of.stats["innovation_joint_max"]))

    play(env, PolicySource.parse(policy).factory(seed), seed, on_step=on_step)
    env.close()
    return found


def summary(values: list[float]) -> str:
    v = np.asarray(values)
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    return (
        f"median {p50:.3f}, p95 {p95:.3f}, p99 {p99:.3f}, "
        f"above {ROOM}: {np.mean(v > ROOM):.4f} of {len(v)} robot-periods"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", default="nmpc")
    ap.add_argument("--object", choices=("ring", "bar"), default="bar")
    ap.add_argument("--n-agents", type=int, nargs="+", default=[2, 4, 6])
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--max-cycles", type=int, default=800)
    ap.add_argument("--seed", type=int, default=202)
    args = ap.parse_args()
    jobs = [(n, k) for n in args.n_agents for k in range(args.episodes)]
    per_case: dict[int, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for n, k in tqdm(jobs, desc="episodes", unit="ep"):
        overrides = {
            "n_agents": n,
            "object": args.object,
            "current": "mild",
            "mismatch": 0.1,
            "max_cycles": args.max_cycles,
        }
        if args.object == "bar":
            overrides["course"] = "mixed"
        found = innovations(args.policy, case_episode_seed(args.seed, "random", k), overrides)
        for lever, values in found.items():
            per_case[n][lever] += values
    for n, by_lever in per_case.items():
        everything = [v for values in by_lever.values() for v in values]
        print(f"{args.object} N={n}: {summary(everything)}")
        for lever in sorted(by_lever):
            print(f"    |l_i| {lever:.1f} m: {summary(by_lever[lever])}")


if __name__ == "__main__":
    main()
