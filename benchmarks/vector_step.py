"""Environment steps per second of ``VectorEnv`` against the single ``parallel_env``.

    python benchmarks/vector_step.py [--num-envs 1 64 256 1024] [--threads 1 0]
                                     [--dtype float32 float64] [--seconds 1.5] [--json F]
    python benchmarks/vector_step.py --backend cuda [--device 0]   # on a GPU

A full environment step (physics with its error control, observations, constraint values,
reward, termination, metrics and automatic resets), actions random in [-0.3, 0.3], on
the paper scenario (N = 2) and the random family with N = 4 (its envs cycle through 32
bank geometries; the first run builds them, ~0.5 s each). The single env is measured in
the same run and every ratio is against it; threads ``0`` means every core this process
may use; the scalar build (``lanes=1``, for CPUs without wide vectors) is measured at
K = 256 with every core. Each figure is the median of three timed windows of
``--seconds``/3.

``--backend cuda``: the same full step on a GPU (actions drawn on the GPU as torch
tensors, every result left there; K defaults to 1,024, 16,384 and 65,536, cases paper
N = 2, random N = 4 and N = 6). ``--device cpu`` runs the CUDA backend's kernels
compiled for the host instead (a check of the path, not a speed figure).
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
from baselines.command_line import non_negative_int, positive_float, positive_int, script_parser
from uvms_env.vector import VectorEnv
from uvms_env.vector.kernels import DTYPES, available_cores

CASES = {
    "paper N=2": ("paper", {}),
    "random N=4": ("random", {"n_agents": 4}),
    "random N=6": ("random", {"n_agents": 6}),
}
CPU_CASES = ["paper N=2", "random N=4"]
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
    backend: str = "cpu",
    device: int | str = 0,
) -> float:
    gpu = {"backend": backend, "device": device} if backend == "cuda" else {"lanes": lanes}
    venv = VectorEnv(
        family,
        num_envs=k,
        dtype=dtype,
        threads=threads,
        **gpu,
        **overrides,
        **POOL.get(family, {}),
    )
    venv.reset(seed=0)
    sync = lambda: None  # noqa: E731
    if backend == "cuda":
        import torch

        where = "cpu" if device == "cpu" else f"cuda:{device}"
        acts = torch.empty((4, k, venv.n, 8), device=where).uniform_(-0.3, 0.3)
        if where != "cpu":
            sync = torch.cuda.synchronize
    else:
        acts = np.random.default_rng(0).uniform(-0.3, 0.3, (4, k, venv.n, 8))
    step = [0]

    def run(m: int) -> int:
        for _ in range(m):
            venv.step(acts[step[0] % 4])
            step[0] += 1
        sync()  # the GPU's queue drained before the clock is read
        return m * k

    run(2)
    return _windows(run, seconds)


def main() -> None:
    parser = script_parser(__file__, __doc__)
    parser.add_argument("--backend", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--device", default="0", help="GPU index, or cpu (emulated kernels)")
    parser.add_argument("--num-envs", type=positive_int, nargs="+")
    parser.add_argument("--threads", type=non_negative_int, nargs="+", default=[1, 0])
    parser.add_argument("--dtype", nargs="+", default=["float32", "float64"], choices=DTYPES)
    parser.add_argument("--cases", nargs="+", choices=list(CASES))
    parser.add_argument("--seconds", type=positive_float, default=1.5)
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    if args.backend == "cuda":
        return cuda_main(args)
    args.num_envs = args.num_envs or [1, 64, 256, 1024]
    args.cases = args.cases or CPU_CASES
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


def cuda_main(args: argparse.Namespace) -> None:
    """The GPU table: env-steps/s per case, dtype and K (no single-env ratio: the GPU
    figures compare with the CPU table of the same machine)."""
    device = args.device if args.device == "cpu" else int(args.device)
    results: list[dict[str, Any]] = []
    for case in args.cases or list(CASES):
        family, overrides = CASES[case]
        print(f"\n{case}, backend cuda, device {device}")
        print(f"{'dtype':>8} {'K':>7} {'env-steps/s':>12} {'robot-steps/s':>14}")
        for dtype in args.dtype:
            for k in args.num_envs or [1024, 16384, 65536]:
                rate = vector_rate(
                    family,
                    overrides,
                    k,
                    dtype,
                    available_cores(),
                    None,
                    args.seconds,
                    "cuda",
                    device,
                )
                n = overrides.get("n_agents", 2)
                print(f"{dtype:>8} {k:>7} {rate:>12,.0f} {rate * n:>14,.0f}")
                results.append(
                    {"case": case, "dtype": dtype, "num_envs": k, "env_steps_per_s": rate}
                )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"backend": "cuda", "device": str(device), "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
