"""Stress the environment as an abusive user would: saturated random and bang-bang inputs
across scenarios and overrides, checking every step.

    python benchmarks/stress.py [--steps 200000] [--seed 0]

For each case it reports the steps run, the worst grasp pose error at the end of any
period (the simulator promises <= 1e-6 m and rad), non-finite observations or rewards
(must be 0), exceptions (must be 0), periods integrated in parts by the error control,
and how the episodes ended (with the reasons of the diverged ones). Exits non-zero when a
promise is broken. The budget is split evenly over the cases.
"""

from __future__ import annotations

import collections
import os
import re
import sys
import time
import traceback

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import non_negative_int, positive_int, script_parser

# (name, family, overrides, share of the step budget): one RK4 substep per period refines
# every period (~20x slower), so that case gets a quarter share.
CASES: list[tuple[str, str, dict, float]] = [
    (
        "paper strong+noise+mismatch0.2",
        "paper",
        {"current": "strong", "sensor_noise": 1.0, "mismatch": 0.2},
        1.0,
    ),
    ("short", "short", {}, 1.0),
    ("short substeps=1", "short", {"substeps": 1}, 0.25),
    ("short damping_scale=0", "short", {"damping_scale": 0.0}, 1.0),
    *[(f"random N={n}", "random", {"n_agents": n}, 1.0) for n in range(2, 7)],
]
INPUTS = ("uniform", "bang-bang")


def run_case(family: str, overrides: dict, steps: int, rng: np.random.Generator) -> dict:
    env = uvms_env.parallel_env(family, internal_wrench_every=0, **overrides)
    out = {
        "steps": 0,
        "worst_pos": 0.0,
        "worst_rot": 0.0,
        "nonfinite": 0,
        "exceptions": 0,
        "ends": collections.Counter(),
        "reasons": collections.Counter(),
    }
    refinements = 0
    while out["steps"] < steps:
        kind = INPUTS[int(rng.integers(len(INPUTS)))]
        try:
            env.reset(seed=int(rng.integers(2**31)))
            while env.agents and out["steps"] < steps:
                n = len(env.agents)
                a = (
                    rng.uniform(-1.5, 1.5, (n, 8))
                    if kind == "uniform"
                    else rng.choice([-1.0, 1.0], (n, 8))
                )
                obs, rew, _, _, infos = env.step(dict(zip(env.agents, a, strict=True)))
                out["steps"] += 1
                pos, rot = env.sim.grasp_error()
                out["worst_pos"] = max(out["worst_pos"], float(pos.max()))
                out["worst_rot"] = max(out["worst_rot"], float(rot.max()))
                values = np.concatenate([np.ravel(list(obs.values())), list(rew.values())])
                out["nonfinite"] += int((~np.isfinite(values)).sum())
                info = next(iter(infos.values()))
                if "episode_end" in info:
                    out["ends"][info["episode_end"]] += 1
                    if info["episode_end"] == "diverged":
                        why = info.get("diverged_reason", "?").split(":", 1)[-1]
                        out["reasons"][re.sub(r"-?[0-9.]+(e-?[0-9]+)?", "#", why)] += 1
            refinements += env.sim.refinements
            env.sim.refinements = 0
        except Exception:  # counting them is the point
            out["exceptions"] += 1
            traceback.print_exc()
    out["refinements"] = refinements
    return out


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--steps", type=positive_int, default=200_000, help="total over all cases")
    ap.add_argument("--seed", type=non_negative_int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    per_share = args.steps / sum(case[3] for case in CASES)
    broken = False
    total = collections.Counter()
    print(
        f"{'case':<32} {'steps':>7} {'max pos err':>11} {'max rot err':>11} {'non-finite':>10} "
        f"{'exceptions':>10} {'refined':>7} {'s':>5}  episode ends"
    )
    for name, family, overrides, share in CASES:
        start = time.perf_counter()
        r = run_case(family, overrides, max(1, round(share * per_share)), rng)
        broken |= r["worst_pos"] > 1e-6 or r["worst_rot"] > 1e-6
        broken |= r["nonfinite"] > 0 or r["exceptions"] > 0
        total.update(
            {"steps": r["steps"], "nonfinite": r["nonfinite"], "exceptions": r["exceptions"]}
        )
        print(
            f"{name:<32} {r['steps']:>7} {r['worst_pos']:>11.2e} {r['worst_rot']:>11.2e} "
            f"{r['nonfinite']:>10} {r['exceptions']:>10} {r['refinements']:>7} "
            f"{time.perf_counter() - start:>5.0f}  {dict(r['ends'])}",
            flush=True,
        )
        for reason, count in r["reasons"].items():
            print(f"{'':<34}diverged x{count}:{reason}")
    print(
        f"total: {total['steps']} steps, {total['nonfinite']} non-finite values, "
        f"{total['exceptions']} exceptions; promises {'BROKEN' if broken else 'kept'}"
    )
    sys.exit(1 if broken else 0)


if __name__ == "__main__":
    main()
