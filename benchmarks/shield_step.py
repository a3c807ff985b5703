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
and the filters only: a training run adds the policy and its updates. A last line times
the QP builder alone (the bar's, horizon 3), per robot: the scalar compiled call against
one lane-parallel call for 64 robots.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import positive_float, positive_int, script_parser, team_size
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


def builder_us() -> tuple[float, float]:
    """(scalar, lanes) microseconds per robot of the filter's QP builder."""
    from nmpc_expert.ocp import ocp_functions
    from nmpc_expert.settings import FILTER_HORIZON, LIBRARY_HORIZONS, NMPCSettings
    from uvms_env.dynamics import ObjectModel
    from uvms_env.dynamics.compiled import BufferCall
    from uvms_env.vector.kernels import BatchedFunction

    s = NMPCSettings.paper(horizon=FILTER_HORIZON)
    funcs = ocp_functions(
        ObjectModel("bar").capacity, FILTER_HORIZON, s.period, s.substeps, LIBRARY_HORIZONS
    )
    scalar = BufferCall(funcs.qp_builder)
    lanes = BatchedFunction(funcs.qp_builder, source=funcs.source)
    rng = np.random.default_rng(0)
    g = funcs.qp_builder
    args = [0.1 * rng.standard_normal(g.size_in(i)[::-1]) for i in range(g.n_in())]
    times = []
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(500):
            scalar(*args)
        times.append((time.perf_counter() - start) / 500)
    k = lanes.padded(64)
    batch = [np.ascontiguousarray(np.repeat(a.reshape(-1, 1), k, 1)) for a in args]
    out = lanes(batch)
    batched = []
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(20):
            lanes(batch, 1, out)
        batched.append((time.perf_counter() - start) / 20 / k)
    return 1e6 * float(np.median(times)), 1e6 * float(np.median(batched))


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--num-envs", type=positive_int, nargs="+", default=[4, 16])
    ap.add_argument("--n-agents", type=team_size, default=2)
    ap.add_argument("--seconds", type=positive_float, default=6.0)
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
    scalar, lanes = builder_us()
    print(f"QP builder per robot: {scalar:.0f} us scalar, {lanes:.0f} us in lanes")


if __name__ == "__main__":
    main()
