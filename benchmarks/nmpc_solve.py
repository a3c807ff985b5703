"""Per-agent decision time of the NMPC expert (one core), at N = 2, 4, 6 robots.

    python benchmarks/nmpc_solve.py [--steps 150] [--solver rti] [--sizes 2 4 6] [--random]
        [--controllers paper observer]

Runs each case in closed loop on the environment (N = 2: the paper scenario; N = 4, 6:
the random family, seed 0; ``--random``: the random family for every N, so that the
object model is the same ring-shaped kind at every size) with one policy per robot and
times every ``act`` call (the whole decision: observation check, object estimate,
reference, QP build and solve).
``--controllers``: the paper's controller and the one with the disturbance observer
(``nmpc_expert.CONTROLLERS``), measured one after the other in the same run (before and
after). The controllers are distributed, so the time per decision must not grow with N. The
first run compiles the OCP of each object shape (~50 s each, cached on disk).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import positive_int, script_parser, team_size
from nmpc_expert import CONTROLLERS, make_policy
from uvms_env.policy import AgentSpec


def measure(
    n: int, steps: int, solver: str, random_only: bool = False, controller: str | None = None
) -> np.ndarray:
    kwargs = {"scenario": "random", "n_agents": n, "seed": 0}
    if n == 2 and not random_only:
        kwargs = {"scenario": "paper"}
    env = uvms_env.parallel_env(**kwargs)
    obs, _ = env.reset(seed=0)
    factory = make_policy(solver, controller)
    pols = {a: factory(AgentSpec.from_scenario(env.scenario, i)) for i, a in enumerate(env.agents)}
    times = []
    for _ in range(steps):
        actions = {}
        for a, p in pols.items():
            t = time.perf_counter()
            actions[a] = p.act(obs[a])
            times.append((time.perf_counter() - t) * 1e3)
        obs, _, term, trunc, _ = env.step(actions)
        if any(term.values()) or any(trunc.values()):
            obs, _ = env.reset(seed=0)
            for p in pols.values():
                p.reset()
    return np.asarray(times)


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--steps", type=positive_int, default=150)
    ap.add_argument("--solver", default="rti", choices=["rti", "ipopt"])
    ap.add_argument("--sizes", type=team_size, nargs="+", default=[2, 4, 6])
    ap.add_argument("--random", action="store_true", help="random family at every N")
    ap.add_argument("--controllers", nargs="+", default=["paper", "observer"], choices=CONTROLLERS)
    args = ap.parse_args()
    if args.solver == "ipopt":
        args.controllers = ["paper"]  # IPOPT solves the paper's controller only
    print(
        f"{'controller':>10} {'N':>3} {'decisions':>9} {'median ms':>10} {'p95 ms':>8} "
        f"{'max ms':>8}"
    )
    for n in args.sizes:
        for controller in args.controllers:
            t = measure(n, args.steps, args.solver, args.random, controller)
            print(
                f"{controller:>10} {n:>3} {len(t):>9} {np.median(t):>10.2f} "
                f"{np.percentile(t, 95):>8.2f} {t.max():>8.2f}"
            )


if __name__ == "__main__":
    main()
