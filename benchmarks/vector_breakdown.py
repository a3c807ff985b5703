"""Where a ``VectorEnv`` step spends its time: inside each compiled kernel, and outside.

    python benchmarks/vector_breakdown.py [--case random] [--n-agents 4] [--num-envs 64]
                                          [--dtype float32] [--threads 1] [--steps 200]
                                          [--repeats 5]

A full environment step (actions random in [-0.3, 0.3], automatic resets, the internal
wrench every step as by default) timed as a whole, and every call of a compiled batch
kernel (``BatchedFunction``) timed on its own, by kernel: the period step with its error
control (``chain_step``: its calls per step are counted, since a period the error
control rejects is integrated again in halves), the team kernel after it
(``env_kernel``), the internal wrench and any other. "outside" is the rest: the task's
rules in array code, the per-environment generators, observation assembly and the calls'
own Python. Each figure is the median over ``--repeats`` runs of ``--steps`` steps
(after a warm-up of 20); the machine's load average is printed with them.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import non_negative_int, positive_int, script_parser, team_size
from uvms_env.vector import VectorEnv
from uvms_env.vector.kernels import DTYPES, BatchedFunction

KERNELS = ("chain_step", "env_kernel", "chain_internal_wrench")


def kernel_kind(name: str) -> str:
    return next((k for k in KERNELS if name.startswith(k)), "other kernels")


class KernelClock:
    """Times every ``BatchedFunction`` call by kernel kind while installed."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._original: Callable[..., Any] = BatchedFunction.__call__

    def __enter__(self) -> KernelClock:
        original, seconds, calls = self._original, self.seconds, self.calls

        def timed(fn: BatchedFunction, *args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return original(fn, *args, **kwargs)
            finally:
                kind = kernel_kind(fn.signature.name)
                seconds[kind] += time.perf_counter() - start
                calls[kind] += 1

        BatchedFunction.__call__ = timed  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        BatchedFunction.__call__ = self._original  # type: ignore[method-assign]


def one_run(venv: VectorEnv, actions: np.ndarray, steps: int) -> dict[str, float]:
    """Per-step milliseconds of one timed run (and chain calls per step)."""
    with KernelClock() as clock:
        start = time.perf_counter()
        for i in range(steps):
            venv.step(actions[i % len(actions)])
        total = time.perf_counter() - start
    row = {"total": total}
    row.update(clock.seconds)
    row["outside"] = total - sum(clock.seconds.values())
    out = {k: 1e3 * v / steps for k, v in row.items()}
    out["chain calls"] = clock.calls["chain_step"] / steps
    return out


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--case", choices=["paper", "random"], default="random")
    ap.add_argument("--n-agents", type=team_size, default=4, help="random family's N")
    ap.add_argument("--num-envs", type=positive_int, default=64)
    ap.add_argument("--dtype", choices=DTYPES, default="float32")
    ap.add_argument("--threads", type=non_negative_int, default=1)
    ap.add_argument("--steps", type=positive_int, default=200)
    ap.add_argument("--repeats", type=positive_int, default=5)
    args = ap.parse_args()
    team = {"n_agents": args.n_agents, "geometry_pool": 32} if args.case == "random" else {}
    venv = VectorEnv(
        args.case, num_envs=args.num_envs, dtype=args.dtype, threads=args.threads, **team
    )
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (4, args.num_envs, venv.n, 8))
    one_run(venv, actions, 20)
    runs = [one_run(venv, actions, args.steps) for _ in range(args.repeats)]
    print(
        f"{args.case} N={venv.n}, K={args.num_envs}, {args.dtype}, {args.threads} thread(s), "
        f"{args.steps} steps x {args.repeats}; load average {os.getloadavg()}"
    )
    print("| part | ms per step (median) | share |")
    print("|---|---|---|")
    total = float(np.median([r["total"] for r in runs]))
    for key in ("total", *KERNELS, "other kernels", "outside"):
        ms = float(np.median([r.get(key, 0.0) for r in runs]))
        print(f"| {key} | {ms:.3f} | {100 * ms / total:.1f} % |")
    print(f"| chain calls per step | {np.median([r['chain calls'] for r in runs]):.2f} | |")


if __name__ == "__main__":
    main()
