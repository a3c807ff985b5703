"""Control periods per second of the truth simulator (one core, random saturated inputs).

    python benchmarks/sim_step.py [--periods 3000] [--repeats 5]

Reports the median and spread over repeats for the paper scenario and the random family
at N = 4 and 6. The first build compiles the step function (cached on disk afterwards).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import positive_int, script_parser
from uvms_env.scenarios import make
from uvms_env.sim import Simulator


def measure(sim: Simulator, periods: int, rng: np.random.Generator) -> float:
    inputs = rng.uniform(-1.2, 1.2, (periods, sim.n, 8)) * sim.tau_max
    sim.reset()
    start = time.perf_counter()
    for u in inputs:
        sim.step(u)
    return periods / (time.perf_counter() - start)


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--periods", type=positive_int, default=3000)
    ap.add_argument("--repeats", type=positive_int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    cases = [("paper", make("paper"))] + [
        (f"random N={n}", make("random", n_agents=n, seed=1)) for n in (4, 6)
    ]
    print(f"{'scenario':<14} {'periods/s (median)':>20} {'min':>8} {'max':>8}")
    for name, scenario in cases:
        sim = Simulator(scenario)
        measure(sim, 1, rng)  # the step compiles (or loads) at the first period: untimed
        rates = [measure(sim, args.periods, rng) for _ in range(args.repeats)]
        print(f"{name:<14} {np.median(rates):>20.0f} {min(rates):>8.0f} {max(rates):>8.0f}")


if __name__ == "__main__":
    main()
