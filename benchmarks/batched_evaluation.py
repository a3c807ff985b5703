"""Learned-rung evaluation speed: episodes per second one by one and batched (one core).

    python benchmarks/batched_evaluation.py [--policy prior] [--n-agents 2 4] [--episodes 8]
                                            [--batch 8] [--max-cycles 300] [--repeats 2]

Plays the same seeded episodes of ``--policy`` (any per-robot policy source of
``baselines.evaluate``) on random teams of each size, mild current and mismatch 0.1,
through ``run_episode`` one by one and through ``play_batched`` with ``--batch`` copies,
alternating within each repeat (the load of a shared machine drifts), and reports the
median episodes per second of each and their ratio. ``--max-cycles`` caps the episodes
so that both play the same periods whatever the policy reaches. Compiles and geometry
builds happen in a warm-up before the timing. The machine and its load are printed.

May import: the standard library, numpy, ``baselines`` and ``uvms_env``.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import positive_int, script_parser, team_size
from baselines.evaluation.batched import play_batched
from baselines.evaluation.episode_row import EpisodeJob, run_episode
from baselines.evaluation.runner import case_episode_seed
from uvms_env.dynamics.compiled import machine_description


def jobs(policy: str, n: int, episodes: int, cycles: int) -> list[EpisodeJob]:
    conditions = (("current", "mild"), ("mismatch", 0.1), ("n_agents", n))
    seeds = [case_episode_seed(0, "random", k) for k in range(episodes)]
    return [
        EpisodeJob(policy, "random", k, s, conditions, cycles, False) for k, s in enumerate(seeds)
    ]


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--policy", default="prior")
    ap.add_argument("--n-agents", type=team_size, nargs="+", default=[2, 4])
    ap.add_argument("--episodes", type=positive_int, default=8)
    ap.add_argument("--batch", type=positive_int, default=8)
    ap.add_argument("--max-cycles", type=positive_int, default=300)
    ap.add_argument("--repeats", type=positive_int, default=2)
    args = ap.parse_args()
    print(f"{machine_description()}; load average before {os.getloadavg()}")
    print("| N | episodes | one by one, episodes/s | batched, episodes/s | ratio |")
    print("|---|---|---|---|---|")
    for n in args.n_agents:
        todo = jobs(args.policy, n, args.episodes, args.max_cycles)
        warm = jobs(args.policy, n, args.episodes, 2)
        play_batched(warm, args.batch)  # compiles, geometries
        for j in warm:
            run_episode(j)
        rates: dict[str, list[float]] = {"single": [], "batched": []}
        for _ in range(args.repeats):
            start = time.perf_counter()
            for j in todo:
                run_episode(j)
            rates["single"].append(len(todo) / (time.perf_counter() - start))
            start = time.perf_counter()
            play_batched(todo, args.batch)
            rates["batched"].append(len(todo) / (time.perf_counter() - start))
        one, many = (float(np.median(rates[k])) for k in ("single", "batched"))
        print(f"| {n} | {len(todo)} | {one:.2f} | {many:.2f} | {many / one:.2f}x |")
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
