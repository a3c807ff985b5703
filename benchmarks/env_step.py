"""Environment steps per second against the bare simulator (one core, random actions).

    python benchmarks/env_step.py [--steps 500] [--repeats 21] [--sizes 2 4 6]

For the paper scenario and the random family at each N: the environment (``env.step``
with uniform random normalized actions: dicts in and out, observations, constraints,
reward, metrics and the internal wrench every step) and the bare simulator
(``Simulator.step``) replaying the same inputs from the same start, so both integrate
the same trajectory (same grasp projections). The environment runs in
constraint_mode="penalize" with a huge max_cycles so that no episode ends inside the
timed loop. Env and simulator runs alternate; the table shows medians over repeats and
the median over repeats of the paired overhead (simulator rate / env rate - 1; target
< 20%), for the default environment and for one without the internal wrench metric
(``internal_wrench_every=0``). The machine's load average is printed: on a shared
machine, prefer many short repeats (the defaults).
"""

from __future__ import annotations

import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import positive_int, script_parser, team_size


def env_rate(env, actions: list[dict[str, np.ndarray]]) -> float:
    env.reset(seed=0)
    start = time.perf_counter()
    for act in actions:
        env.step(act)
    return len(actions) / (time.perf_counter() - start)


def sim_rate(env, taus: np.ndarray) -> float:
    sim = env.sim
    sim.reset(seed=0)  # no mismatch, no current: the env's start and dynamics
    start = time.perf_counter()
    for tau in taus:
        sim.step(tau)
    return len(taus) / (time.perf_counter() - start)


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--steps", type=positive_int, default=500)
    ap.add_argument("--repeats", type=positive_int, default=21)
    ap.add_argument("--sizes", type=team_size, nargs="*", default=[2, 4, 6], help="random family N")
    args = ap.parse_args()
    cases = [("paper", "paper", {})] + [
        (f"random N={n}", "random", {"n_agents": n, "seed": 1}) for n in args.sizes
    ]
    rng = np.random.default_rng(0)
    print(f"{platform.processor() or platform.machine()}, load average {os.getloadavg()}")
    print(
        f"{'scenario':<14} {'sim steps/s':>12} {'env steps/s':>12} {'env overhead':>13} "
        f"{'no wrench':>12} {'overhead':>12}"
    )
    for name, family, overrides in cases:
        env = uvms_env.parallel_env(family, max_cycles=10**9, **overrides)
        agents = env.possible_agents
        raw = rng.uniform(-1.0, 1.0, (args.steps, len(agents), 8)).astype(np.float32)
        actions = [{a: row[i] for i, a in enumerate(agents)} for row in raw]
        taus = raw.astype(float) * env.sim.tau_max
        lean = uvms_env.parallel_env(family, max_cycles=10**9, internal_wrench_every=0, **overrides)
        env_rate(env, actions[:50])  # warm up
        env_rate(lean, actions[:50])
        sims, envs, leans = [], [], []
        for _ in range(args.repeats):
            envs.append(env_rate(env, actions))
            sims.append(sim_rate(env, taus))
            leans.append(env_rate(lean, actions))
        # paired: each env run against the simulator run next to it (the load drifts)
        sims_a = np.array(sims)
        over = np.median(sims_a / np.array(envs)) - 1
        over_lean = np.median(sims_a / np.array(leans)) - 1
        s, e = float(np.median(sims)), float(np.median(envs))
        print(
            f"{name:<14} {s:>12.0f} {e:>12.0f} {100 * over:>12.1f}% "
            f"{float(np.median(leans)):>12.0f} {100 * over_lean:>12.1f}%"
        )


if __name__ == "__main__":
    main()
