"""Per-agent decision time of the NMPC expert (one core), at N = 2, 4, 6 robots.

    python benchmarks/nmpc_solve.py [--steps 150] [--solver rti] [--sizes 2 4 6] [--random]
        [--controllers paper observer] [--compare PATH]

Runs each case in closed loop on the environment (N = 2: the paper scenario; N = 4, 6:
the random family, seed 0; ``--random``: the random family for every N, so that the
object model is the same ring-shaped kind at every size) with one policy per robot and
times every ``act`` call (the whole decision: observation check, object estimate,
reference, QP build and solve): its wall time and, ``cpu ms``, its thread's CPU time,
which other jobs on the cores change less (they still share the caches).
``--controllers``: the paper's controller and the one with the disturbance observer
(``nmpc_expert.CONTROLLERS``), measured one after the other in the same run (before and
after). The controllers are distributed, so the time per decision must not grow with N.
``--compare PATH``: the same cases for another checkout too (PATH: its root, e.g. main's
HEAD unpacked with ``git archive``), each case in a fresh process per checkout, the
checkouts alternating, so that a change of load hits both; the last column is this
checkout's median over the other's. The first run compiles the OCP library (one for every
object of a strip capacity, cached on disk); the machine and its load are printed with the
table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import positive_int, script_parser, team_size
from nmpc_expert import CONTROLLERS, make_policy
from uvms_env.policy import AgentSpec

HERE = Path(__file__).resolve().parents[1]  # this checkout's root


def measure(
    n: int, steps: int, solver: str, random_only: bool = False, controller: str | None = None
) -> np.ndarray:
    """(2, decisions): each decision's wall time and its thread's CPU time, ms."""
    kwargs = {"scenario": "random", "n_agents": n, "seed": 0}
    if n == 2 and not random_only:
        kwargs = {"scenario": "paper"}
    env = uvms_env.parallel_env(**kwargs)
    obs, _ = env.reset(seed=0)
    factory = make_policy(solver, controller)
    pols = {a: factory(AgentSpec.from_scenario(env.scenario, i)) for i, a in enumerate(env.agents)}
    times, cpu = [], []
    for _ in range(steps):
        actions = {}
        for a, p in pols.items():
            t, c = time.perf_counter(), time.thread_time()
            actions[a] = p.act(obs[a])
            times.append((time.perf_counter() - t) * 1e3)
            cpu.append((time.thread_time() - c) * 1e3)
        obs, _, term, trunc, _ = env.step(actions)
        if any(term.values()) or any(trunc.values()):
            obs, _ = env.reset(seed=0)
            for p in pols.values():
                p.reset()
    return np.asarray([times, cpu])


def measured_in(checkout: Path, argv: list[str]) -> np.ndarray:
    """``measure`` in a fresh process on ``checkout``'s packages (``--one``'s output)."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    out = subprocess.run(
        [sys.executable, __file__, *argv], env=env, check=True, capture_output=True, text=True
    )
    return np.asarray(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--steps", type=positive_int, default=150)
    ap.add_argument("--solver", default="rti", choices=["rti", "ipopt"])
    ap.add_argument("--sizes", type=team_size, nargs="+", default=[2, 4, 6])
    ap.add_argument("--random", action="store_true", help="random family at every N")
    ap.add_argument("--controllers", nargs="+", default=["paper", "observer"], choices=CONTROLLERS)
    ap.add_argument("--compare", type=Path, default=None, help="another checkout's root")
    ap.add_argument("--one", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.solver == "ipopt":
        args.controllers = ["paper"]  # IPOPT solves the paper's controller only
    if args.one is not None:  # a worker: one case, its times as JSON
        t = measure(int(args.one[0]), args.steps, args.solver, args.random, args.one[1])
        print(json.dumps(t.tolist()))  # wall and CPU times
        return
    if args.compare is not None and not (args.compare / "nmpc_expert").is_dir():
        ap.error(f"--compare {args.compare}: not a checkout (no nmpc_expert folder there)")
    from uvms_env.dynamics.compiled import machine_description

    print(f"{machine_description()}; load average before {os.getloadavg()}")
    checkouts = [("this", HERE)] + ([("compared", args.compare)] if args.compare else [])
    print(
        f"{'checkout':>9} {'controller':>10} {'N':>3} {'decisions':>9} {'median ms':>10} "
        f"{'p95 ms':>8} {'max ms':>8} {'cpu ms':>7}{' ratio':>7}{' cpu ratio':>10}"
    )
    for n in args.sizes:
        for controller in args.controllers:
            medians: dict[str, tuple[float, float]] = {}
            for name, root in checkouts:
                if args.compare is None:
                    t, c = measure(n, args.steps, args.solver, args.random, controller)
                else:
                    argv = ["--one", str(n), controller, "--steps", str(args.steps)]
                    argv += ["--solver", args.solver] + (["--random"] if args.random else [])
                    t, c = measured_in(root, argv)
                medians[name] = (float(np.median(t)), float(np.median(c)))
                ratio = " " * 17
                if name == "compared":
                    mine, theirs = medians["this"], medians[name]
                    ratio = f"{mine[0] / theirs[0]:>7.2f}{mine[1] / theirs[1]:>10.2f}"
                print(
                    f"{name:>9} {controller:>10} {n:>3} {len(t):>9} {np.median(t):>10.2f} "
                    f"{np.percentile(t, 95):>8.2f} {t.max():>8.2f} {np.median(c):>7.2f}{ratio}",
                    flush=True,
                )
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
