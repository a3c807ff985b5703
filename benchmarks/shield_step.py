"""Robot-steps per second of ``VectorEnv`` with the training shield (every robot's command
through its own safety filter), batched QP builders against one filter after another.

    python benchmarks/shield_step.py [--num-envs 4 16] [--n-agents 2] [--seconds 6]

`random` N robots, float64, residual actions N(0, 0.05^2) around each robot's steady input
a_ss (``action_mode=residual``, scale 1: proposals near what holds the load, the size of an
initialized actor's exploration).
Three settings per K: no filter, ``Shield(batched=False)`` and ``Shield()`` (one
lane-parallel call of the K N QP builders per step). Each figure is the median of three
timed windows of ``--seconds``/3 after one warm-up window; the first run compiles the
lane-parallel builder (about a minute, cached on disk). Figures are for the environment
and the filters only: a training run adds the policy and its updates.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.rl.shield import Shield
from uvms_env.vector import VectorEnv


def rate(k: int, n: int, mode: str, seconds: float) -> float:
    env = VectorEnv(
        "random", num_envs=k, n_agents=n, dtype="float64", threads=1, internal_wrench_every=0,
        action_mode="residual", observation_mode="raw", residual_scale=1.0,
    )  # fmt: skip
    if mode != "none":
        Shield(env, batched=mode == "batched")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    windows = []
    for w in range(4):
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 3:
            env.step(0.05 * rng.standard_normal((k, n, 8)))
            steps += 1
        if w:
            windows.append(steps * k * n / (time.perf_counter() - start))
    return float(np.median(windows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--num-envs", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--n-agents", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=6.0)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; random N = {args.n_agents}, float64")
    print("| K | robots | no filter | one by one | batched builders | batched / one by one |")
    print("|---|---|---|---|---|---|")
    for k in args.num_envs:
        r = {m: rate(k, args.n_agents, m, args.seconds) for m in ("none", "single", "batched")}
        print(
            f"| {k} | {k * args.n_agents} | {r['none']:,.0f} | {r['single']:,.0f} | "
            f"{r['batched']:,.0f} | {r['batched'] / r['single']:.2f}x |"
        )


if __name__ == "__main__":
    main()
