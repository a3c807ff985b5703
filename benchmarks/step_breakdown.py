"""Where an environment step spends its time: inside each compiled call, and outside.

    python benchmarks/step_breakdown.py [--env vector] [--case random] [--n-agents 4]
                                        [--num-envs 64] [--dtype float32] [--threads 1]
                                        [--steps 200] [--repeats 5]
    python benchmarks/step_breakdown.py --env single --case paper

A full environment step (actions random in [-0.3, 0.3], the internal wrench every step
as by default) timed as a whole, and every compiled call timed on its own, by function:
the period step with its error control (``chain_step``: its calls per step are counted,
since a period the error control rejects is integrated again in halves), the team
kernel after it (``env_kernel``, the internal wrench inside where its metric is on)
and any other. ``--env vector``:
``VectorEnv`` with K = ``--num-envs`` (automatic resets; the batch kernels,
``BatchedFunction``); ``--env single``: ``parallel_env`` (``constraint_mode="penalize"``
and no time limit, so that no episode ends inside the timed loop; the CasADi calls,
``BufferCall``). "outside" is the rest: the task's rules in array code, the
per-environment generators, observation assembly and the calls' own Python. Each figure
is the median over ``--repeats`` runs of ``--steps`` steps (after a warm-up of 20); the
machine's load average is printed with them.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import non_negative_int, positive_int, script_parser, team_size
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.vector import VectorEnv
from uvms_env.vector.kernels import DTYPES, BatchedFunction

KERNELS = ("chain_step", "env_kernel")


def kernel_kind(name: str) -> str:
    return next((k for k in KERNELS if name.startswith(k)), "other kernels")


# the compiled callables and how each names its function: the batch kernels (VectorEnv)
# and the zero-copy CasADi calls (parallel_env; ``again`` re-runs the last bound call)
CALLS: tuple[tuple[type, str, Callable[[Any], str]], ...] = (
    (BatchedFunction, "__call__", lambda f: f.signature.name),
    (BufferCall, "__call__", lambda f: f.fn.name()),
    (BufferCall, "again", lambda f: f.fn.name()),
)


class KernelClock:
    """Times every compiled call by kernel kind while installed."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._originals = [(cls, attr, getattr(cls, attr)) for cls, attr, _ in CALLS]

    def __enter__(self) -> KernelClock:
        for (cls, attr, original), (_, _, name_of) in zip(self._originals, CALLS, strict=True):
            setattr(cls, attr, self._timed(original, name_of))
        return self

    def _timed(self, original: Callable[..., Any], name_of: Callable[[Any], str]) -> Any:
        seconds, calls = self.seconds, self.calls

        def timed(fn: Any, *args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return original(fn, *args, **kwargs)
            finally:
                kind = kernel_kind(name_of(fn))
                seconds[kind] += time.perf_counter() - start
                calls[kind] += 1

        return timed

    def __exit__(self, *exc: object) -> None:
        for cls, attr, original in self._originals:
            setattr(cls, attr, original)


def one_run(step: Callable[[int], Any], steps: int) -> dict[str, float]:
    """Per-step milliseconds of one timed run of ``step(i)`` (and chain calls per step)."""
    with KernelClock() as clock:
        start = time.perf_counter()
        for i in range(steps):
            step(i)
        total = time.perf_counter() - start
    row = {"total": total}
    row.update(clock.seconds)
    row["outside"] = total - sum(clock.seconds.values())
    out = {k: 1e3 * v / steps for k, v in row.items()}
    out["chain calls"] = clock.calls["chain_step"] / steps
    return out


def vector_step(args: Any) -> tuple[Callable[[int], Any], str]:
    """``VectorEnv``'s step on random actions, and its description."""
    team = {"n_agents": args.n_agents, "geometry_pool": 32} if args.case == "random" else {}
    venv = VectorEnv(
        args.case, num_envs=args.num_envs, dtype=args.dtype, threads=args.threads, **team
    )
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (4, args.num_envs, venv.n, 8))
    about = f"VectorEnv {args.case} N={venv.n}, K={args.num_envs}, {args.dtype}, "
    return (lambda i: venv.step(actions[i % 4])), about + f"{args.threads} thread(s)"


def single_step(args: Any) -> tuple[Callable[[int], Any], str]:
    """``parallel_env``'s step on random actions (no episode ends), and its description."""
    team = {"n_agents": args.n_agents, "seed": 1} if args.case == "random" else {}
    env = uvms_env.parallel_env(args.case, constraint_mode="penalize", max_cycles=10**9, **team)
    env.reset(seed=0)
    draws = np.random.default_rng(0).uniform(-0.3, 0.3, (16, env.n, 8))
    actions = [dict(zip(env.possible_agents, a, strict=True)) for a in draws]
    return (lambda i: env.step(actions[i % 16])), f"parallel_env {args.case} N={env.n}"


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--env", choices=["vector", "single"], default="vector")
    ap.add_argument("--case", choices=["paper", "random"], default="random")
    ap.add_argument("--n-agents", type=team_size, default=4, help="random family's N")
    ap.add_argument("--num-envs", type=positive_int, default=64)
    ap.add_argument("--dtype", choices=DTYPES, default="float32")
    ap.add_argument("--threads", type=non_negative_int, default=1)
    ap.add_argument("--steps", type=positive_int, default=200)
    ap.add_argument("--repeats", type=positive_int, default=5)
    args = ap.parse_args()
    step, about = (vector_step if args.env == "vector" else single_step)(args)
    one_run(step, 20)
    runs = [one_run(step, args.steps) for _ in range(args.repeats)]
    print(f"{about}, {args.steps} steps x {args.repeats}; load average {os.getloadavg()}")
    print("| part | ms per step (median) | share |")
    print("|---|---|---|")
    total = float(np.median([r["total"] for r in runs]))
    for key in ("total", *KERNELS, "other kernels", "outside"):
        ms = float(np.median([r.get(key, 0.0) for r in runs]))
        print(f"| {key} | {ms:.3f} | {100 * ms / total:.1f} % |")
    print(f"| chain calls per step | {np.median([r['chain calls'] for r in runs]):.2f} | |")


if __name__ == "__main__":
    main()
