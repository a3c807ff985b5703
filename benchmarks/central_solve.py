"""Team decision time of the centralized NMPC (one core), at N = 2, 4, 6 robots.

    python benchmarks/central_solve.py [--steps 150] [--sizes 2 4 6] [--parts]

Plays the centralized NMPC (``nmpc_expert.central``, a team policy) in closed loop on the
environment through the episode driver (``uvms_env.episode.play_team``; N = 2: the
``paper`` scenario, N = 4, 6: the random family, seed 0) and reports the time of every
team decision (the whole ``act``: state check, reference, steady inputs, the horizon's
period steps, the linearization, condensing and the screened QP), median, p95 and max.
``--parts``: also the median time of each compiled part (the horizon's period steps and
the linearization call, with its discretization in numpy) at the first state, where the
rest is numpy and DAQP. The first run compiles the linearization of each team size
(~10-20 s, cached on disk).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # BLAS threads collapse on shared cores

import numpy as np

import uvms_env
from baselines.command_line import positive_int, script_parser, team_size
from nmpc_expert import CentralNMPC, make_central_policy
from uvms_env.episode import play_team


def make_env(n: int, steps: int):
    if n == 2:
        return uvms_env.parallel_env("paper", max_cycles=steps)
    return uvms_env.parallel_env("random", n_agents=n, seed=0, max_cycles=steps)


def measure(n: int, steps: int) -> np.ndarray:
    """Every team decision's time (ms) over ``steps`` periods of one episode."""
    episode = play_team(make_env(n, steps), make_central_policy(), seed=0)
    return episode.decision_ms.ravel()


def parts(n: int, repeats: int = 20) -> dict[str, float]:
    """Median ms of the compiled parts of one decision at the episode's first state."""
    env = make_env(n, 1)
    env.reset(seed=0)
    team = CentralNMPC(env.scenario)
    team.reset()
    state = env.state()
    team.act(state)
    plan, model = team.solver, team.model

    def timed(fn) -> float:
        out = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            out.append((time.perf_counter() - t) * 1e3)
        return float(np.median(out))

    return {
        "decision": timed(lambda: team.act(state)),
        "period steps": timed(
            lambda: [model.predict(plan.xbar[k], plan.abar[k]) for k in range(team.horizon)]
        ),
        "linearization": timed(lambda: model.linearize(plan.xbar, plan.abar)),
    }


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--steps", type=positive_int, default=150)
    ap.add_argument("--sizes", type=team_size, nargs="+", default=[2, 4, 6])
    ap.add_argument("--parts", action="store_true", help="also time the compiled parts")
    args = ap.parse_args()
    print(f"{'N':>3} {'decisions':>9} {'median ms':>10} {'p95 ms':>8} {'max ms':>8}")
    for n in args.sizes:
        t = measure(n, args.steps)
        print(
            f"{n:>3} {len(t):>9} {np.median(t):>10.2f} {np.percentile(t, 95):>8.2f} {t.max():>8.2f}"
        )
    if args.parts:
        for n in args.sizes:
            print(f"N = {n}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in parts(n).items()))


if __name__ == "__main__":
    main()
