"""Environment steps per second with the acoustic channel off and on, in one run.

    python benchmarks/comm_step.py [--presets ideal atm900] [--num-envs 256]
                                   [--repeats 7] [--steps 300] [--backend cpu|cuda]

The single ``parallel_env`` on the paper scenario (target with the channel on: >= 1,800
steps/s) and ``VectorEnv`` float32 with K environments (target: within 15% of the
channel off), each with the channel off and with every preset asked for. Actions: inputs
uniform in [-0.3, 0.3]; under a channel every robot sends with probability 1/2 a random
message each step (the channel's busiest useful case: its slots are taken, its inboxes
fill). Runs alternate off / on within each repeat (the load of a shared machine drifts);
the table shows medians over repeats and the median of the paired ratios on / off.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import positive_int, script_parser
from uvms_env.vector import VectorEnv


def actions(size: int, shape: tuple[int, ...], count: int, rng: np.random.Generator) -> np.ndarray:
    a = rng.uniform(-0.3, 0.3, (count, *shape, size)).astype(np.float32)
    if size > 8:  # the send flag: every other robot, on average; random messages
        a[..., 8] = rng.choice([-1.0, 1.0], (count, *shape))
        a[..., 9:] = rng.uniform(-1, 1, a[..., 9:].shape)
    return a


def single_runner(comm: str | None, steps: int):
    env = uvms_env.parallel_env("paper", comm=comm, max_cycles=10**9)
    agents = env.possible_agents
    size = env.action_space(agents[0]).shape[0]
    raw = actions(size, (env.n,), steps, np.random.default_rng(0))
    acts = [{a: row[i] for i, a in enumerate(agents)} for row in raw]

    def run() -> float:
        env.reset(seed=0)
        start = time.perf_counter()
        for a in acts:
            env.step(a)
        return steps / (time.perf_counter() - start)

    run()  # warm up
    return run


def vector_runner(comm: str | None, k: int, steps: int, backend: str):
    extra = {"backend": "cuda"} if backend == "cuda" else {}
    venv = VectorEnv("paper", num_envs=k, dtype="float32", comm=comm, max_cycles=10**9, **extra)
    size = venv.single_action_space.shape[0]
    acts = actions(size, (k, venv.n), 8, np.random.default_rng(0))
    sync = lambda: None  # noqa: E731
    if backend == "cuda":
        import torch

        acts = torch.as_tensor(acts, device="cuda")
        sync = torch.cuda.synchronize
    venv.reset(seed=0)

    def run() -> float:
        sync()
        start = time.perf_counter()
        for i in range(steps):
            venv.step(acts[i % 8])
        sync()
        return steps * k / (time.perf_counter() - start)

    run()
    return run


def table(title: str, runners: dict[str, object], repeats: int) -> None:
    rates: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(repeats):
        for name, run in runners.items():
            rates[name].append(run())  # type: ignore[operator]
    off = np.array(rates["off"])
    print(f"\n{title}")
    print(f"{'comm':<16} {'env-steps/s':>12} {'on / off':>9}")
    for name, r in rates.items():
        ratio = float(np.median(np.array(r) / off))
        print(f"{name:<16} {np.median(r):>12,.0f} {ratio:>9.3f}")


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--presets", nargs="+", default=["ideal", "atm900"])
    ap.add_argument("--num-envs", type=positive_int, default=256)
    ap.add_argument("--repeats", type=positive_int, default=7)
    ap.add_argument("--steps", type=positive_int, default=300, help="single env steps per run")
    ap.add_argument("--vector-steps", type=positive_int, default=40, help="VectorEnv steps per run")
    ap.add_argument("--backend", choices=["cpu", "cuda"], default="cpu")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()}")
    names = ["off", *args.presets]
    comm = {name: (None if name == "off" else name) for name in names}
    if args.backend == "cpu":
        single = {name: single_runner(comm[name], args.steps) for name in names}
        table("parallel_env, paper (N = 2)", single, args.repeats)
    vector = {
        name: vector_runner(comm[name], args.num_envs, args.vector_steps, args.backend)
        for name in names
    }
    table(
        f"VectorEnv float32, paper, K = {args.num_envs}, backend {args.backend}",
        vector,
        args.repeats,
    )


if __name__ == "__main__":
    main()
