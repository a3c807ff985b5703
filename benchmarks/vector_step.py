"""Environment steps per second of ``VectorEnv`` against the single ``parallel_env``.

    python benchmarks/vector_step.py [--num-envs 1 64 256 1024] [--threads 1 0]
                                     [--dtype float32 float64] [--seconds 1.5] [--json F]

A full environment step (physics with its error control, observations, constraint values,
reward, termination, metrics and automatic resets), actions random in [-0.3, 0.3], on
the paper scenario (N = 2) and the random family with N = 4 (its envs cycle through 32
bank geometries; the first run builds them, ~0.5 s each). The single env is measured in
the same run and every ratio is against it; threads ``0`` means every core this process
may use; the scalar build (``lanes=1``, for CPUs without wide vectors) is measured at
K = 256 with every core. Each figure is the median of three timed windows of
``--seconds``/3.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from uvms_env.vector import VectorEnv
from uvms_env.vector.kernels import available_cores

CASES = {"paper N=2": ("paper", {}), "random N=4": ("random", {"n_agents": 4})}
POOL = {"random": {"geometry_pool": 32}}


def _windows(run_steps, seconds: float) -> float:
    """Median rate over three windows of ``seconds / 3`` each (``run_steps(m)`` -> items)."""
    rates = []
    for _ in range(3):
        start, items = time.perf_counter(), 0
        while time.perf_counter() - start < seconds / 3:
            items += run_steps(4)
        rates.append(items / (time.perf_counter() - start))
    return float(np.median(rates))


def single_rate(family: str, overrides: dict, seconds: float) -> float:
    env = uvms_env.parallel_env(family, **overrides)
    env.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-0.3, 0.3, (16, env.n, 8))
    agents = env.possible_agents
    step = [0]

    def run(m: int) -> int:
        for _ in range(m):
            a = acts[step[0] % 16]
            step[0] += 1
            env.step({ag: a[i] for i, ag in enumerate(agents)})
            if not env.agents:
                env.reset()
        return m

    run(4)
    return _windows(run, seconds)


def vector_rate(
    family: str,
    overrides: dict,
    k: int,
    dtype: str,
    threads: int,
    lanes: int | None,
    seconds: float,
) -> float:
    venv = VectorEnv(
        family,
        num_envs=k,
        dtype=dtype,
        threads=threads,
        lanes=lanes,
        **overrides,
        **POOL.get(family, {}),
    )
    venv.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-0.3, 0.3, (4, k, venv.n, 8))
    step = [0]

    def run(m: int) -> int:
        for _ in range(m):
            venv.step(acts[step[0] % 4])
            step[0] += 1
        return m * k

    run(2)
    return _windows(run, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[1, 64, 256, 1024])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 0])
    parser.add_argument("--dtype", nargs="+", default=["float32", "float64"])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--seconds", type=float, default=1.5)
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    cores = available_cores()
    results: list[dict[str, Any]] = []
    print(f"cores: {cores}")
    for case in args.cases:
        family, overrides = CASES[case]
        single = single_rate(family, overrides, args.seconds)
        print(f"\n{case}: single parallel_env {single:,.0f} env-steps/s")
        print(f"{'dtype':>8} {'lanes':>6} {'threads':>7} {'K':>6} {'env-steps/s':>12} {'ratio':>7}")
        configs = [
            (dtype, None, threads or cores, k)
            for dtype in args.dtype
            for threads in args.threads
            for k in args.num_envs
        ]
        configs += [(dtype, 1, cores, 256) for dtype in args.dtype]  # the scalar build
        for dtype, lanes, threads, k in configs:
            rate = vector_rate(family, overrides, k, dtype, threads, lanes, args.seconds)
            shown = "scalar" if lanes == 1 else "simd"
            print(
                f"{dtype:>8} {shown:>6} {threads:>7} {k:>6} {rate:>12,.0f} {rate / single:>6.1f}x"
            )
            results.append(
                {
                    "case": case,
                    "dtype": dtype,
                    "lanes": shown,
                    "threads": threads,
                    "num_envs": k,
                    "env_steps_per_s": rate,
                    "single_env_steps_per_s": single,
                    "ratio": rate / single,
                }
            )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"cores": cores, "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
