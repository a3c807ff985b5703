"""Environment-periods per second of the batched truth simulator against the single one.

    python benchmarks/batched_step.py [--backend cpu cuda] [--num-envs 256 1024 ...]
                                      [--dtype float64 float32] [--threads 1 0] [--periods 20]

Physics only (the period step with its projection and error control, saturated random
inputs), which is what ``uvms_env.vector.BatchedSimulator`` batches today. CPU: SIMD
lanes (the widest this CPU has; ``--lanes 1`` for the scalar build) and threads
(``0`` = every core); CUDA: one GPU thread per environment, arrays on the GPU. Each
figure is the median over repeats; the single simulator is measured in the same run.
Also checks agreement: float64 batched vs single simulators over ``--check-periods``
periods, and float32 vs float64.
"""

from __future__ import annotations

import itertools
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import non_negative_int, positive_int, script_parser, team_size
from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.vector.batched_simulator import BatchedSimulator
from uvms_env.vector.kernels import DTYPES


def single_rate(scenario, periods: int, rng: np.random.Generator) -> float:
    sim = Simulator(scenario)
    u = rng.uniform(-1.2, 1.2, (periods, sim.n, 8)) * sim.tau_max
    sim.step(u[0])  # the step compiles (or loads) at the first period: untimed
    start = time.perf_counter()
    for uk in u:
        sim.step(uk)
    return periods / (time.perf_counter() - start)


def batched_rate(bsim: BatchedSimulator, periods: int, repeats: int) -> float:
    xp, k, n = bsim.xp, bsim.num_envs, bsim.n
    tau_max = xp.asarray(bsim.tau_max)
    inputs = [
        xp.asarray(np.random.default_rng(r).uniform(-1.2, 1.2, (k, n, 8))) * tau_max
        for r in range(4)
    ]
    bsim.step(inputs[0])  # warm-up (first launch, caches)
    rates = []
    for _ in range(repeats):
        bsim.reset(np.arange(k), np.arange(k))
        sync(xp)
        start = time.perf_counter()
        for p in range(periods):
            bsim.step(inputs[p % 4])
        sync(xp)
        rates.append(k * periods / (time.perf_counter() - start))
    return float(np.median(rates))


def sync(xp) -> None:
    if xp is not np:
        xp.cuda.Device().synchronize()


def agreement(scenario, backend: str, periods: int) -> tuple[float, float]:
    """Max |x| deviation of float64 batched (backend) vs single simulators, and of
    float32 vs float64 batched, after ``periods`` periods of random inputs."""
    k = 16
    rng = np.random.default_rng(7)
    u = rng.uniform(-1.0, 1.0, (periods, k, scenario.n_agents, 8))
    sims = [Simulator(scenario) for _ in range(k)]
    for i, sim in enumerate(sims):
        sim.reset(seed=i)
    b64 = BatchedSimulator(scenario, k, backend=backend, dtype="float64")
    b32 = BatchedSimulator(scenario, k, backend=backend, dtype="float32")
    for b in (b64, b32):
        b.reset(np.arange(k), np.arange(k))
    tau_max = sims[0].tau_max
    for uk in u:
        for sim, ui in zip(sims, uk, strict=True):
            sim.step(ui * tau_max)
        b64.step(b64.xp.asarray(uk * tau_max))
        b32.step(b32.xp.asarray((uk * tau_max).astype(np.float32)))
    x64 = to_numpy(b64.state())
    single = np.stack([sim.flat_state for sim in sims])
    return float(np.abs(x64 - single).max()), float(np.abs(to_numpy(b32.state()) - x64).max())


def to_numpy(a) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--backend", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    ap.add_argument("--num-envs", type=positive_int, nargs="+", default=[64, 256, 1024])
    ap.add_argument("--dtype", nargs="+", default=["float64", "float32"], choices=DTYPES)
    ap.add_argument(
        "--threads", type=non_negative_int, nargs="+", default=[1, 0], help="CPU; 0: all"
    )
    ap.add_argument("--lanes", type=positive_int, default=None, help="CPU SIMD lanes (1: scalar)")
    ap.add_argument(
        "--block", type=positive_int, nargs="+", default=[128], help="CUDA threads/block"
    )
    ap.add_argument("--no-check", action="store_true", help="skip the agreement check")
    ap.add_argument("--n-agents", type=team_size, nargs="+", default=[2])
    ap.add_argument("--periods", type=positive_int, default=20)
    ap.add_argument("--repeats", type=positive_int, default=3)
    ap.add_argument("--check-periods", type=positive_int, default=100)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    for n in args.n_agents:
        scenario = make("paper") if n == 2 else make("random", n_agents=n, seed=1)
        single = single_rate(scenario, 500, rng)
        print(f"N = {n}: single simulator {single:,.0f} periods/s (one core)", flush=True)
        for backend in args.backend:
            if not args.no_check:
                dev64, dev32 = agreement(scenario, backend, args.check_periods)
                print(
                    f"  {backend}: after {args.check_periods} periods, float64 batched vs "
                    f"single {dev64:.1e}, float32 vs float64 {dev32:.1e}",
                    flush=True,
                )
            threads = args.threads if backend == "cpu" else [0]
            blocks = args.block if backend == "cuda" else [0]
            for dtype, th, block, k in itertools.product(
                args.dtype, threads, blocks, args.num_envs
            ):
                bsim = BatchedSimulator(
                    scenario,
                    k,
                    backend=backend,
                    dtype=dtype,
                    threads=th or os.cpu_count(),
                    lanes=args.lanes,
                )
                if backend == "cuda":
                    bsim._fn.block = block
                    where = f"GPU, block {block}"
                else:
                    where = f"lanes {bsim._fn.lanes}, threads {bsim.threads}"
                rate = batched_rate(bsim, args.periods, args.repeats)
                print(
                    f"  {backend} {dtype} K = {k:>7} ({where}): {rate:>12,.0f} "
                    f"env-periods/s = {rate / single:6.1f}x the single simulator",
                    flush=True,
                )


if __name__ == "__main__":
    main()
