"""First-use compile time of the expert's and the simulator's libraries, and what the cut
costs at run time: the generated C compiled whole in one unit against cut into parts over
parallel units (``uvms_env.dynamics.split_source``), measured in one run.

    python benchmarks/compile_time.py [--scenarios paper random] [--steps 300]

For each way and scenario, a fresh process with an empty compile cache builds the
environment and one expert per robot, plays ``--steps`` periods (the paper scenario: the
main job's episode; ``random``: the evaluator's first ``nmpc`` episode, N = 2) and reports
each library's compile seconds (the cache's compile log), the median decision time per
robot and the median environment step. The ways alternate scenario by scenario, so that
a change of load hits both.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

WAYS = ("whole", "split")


def worker(way: str, scenario: str, steps: int) -> dict:
    """One way in this (fresh) process: compile everything, play, time."""
    import numpy as np

    import uvms_env
    import uvms_env.dynamics.compiled as compiled
    from nmpc_expert import make_policy
    from uvms_env.policy import AgentSpec

    if way == "whole":  # the generated C as CasADi writes it, one unit
        compiled.cut_long_functions = lambda source: source  # type: ignore[assignment]
        compiled.default_units = lambda source: 1  # type: ignore[assignment]
    start = time.perf_counter()
    env = uvms_env.parallel_env(scenario=scenario, seed=0)
    obs, _ = env.reset(seed=0)
    factory = make_policy("rti", None)
    pols = {a: factory(AgentSpec.from_scenario(env.scenario, i)) for i, a in enumerate(env.agents)}
    decide, step = [], []
    for _ in range(steps):
        actions = {}
        for a, p in pols.items():
            t = time.perf_counter()
            actions[a] = p.act(obs[a])
            decide.append(time.perf_counter() - t)
        t = time.perf_counter()
        obs, _, term, trunc, _ = env.step(actions)
        step.append(time.perf_counter() - t)
        if any(term.values()) or any(trunc.values()):
            break
    log = compiled.cache_dir() / "compile_log.jsonl"
    rows = [json.loads(r) for r in log.read_text().splitlines()] if log.exists() else []
    # the first decision and step hold the compiles: the medians leave them out
    return {
        "compiles": rows,
        "decision_ms": 1e3 * float(np.median(decide[len(pols) :])),
        "step_ms": 1e3 * float(np.median(step[1:])),
        "wall_s": time.perf_counter() - start,
    }


def run(way: str, scenario: str, steps: int) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "UVMS_ENV_CACHE": cache}
        cmd = [sys.executable, __file__, "--worker", way, "--scenarios", scenario]
        out = subprocess.run(
            [*cmd, "--steps", str(steps)], env=env, check=True, capture_output=True, text=True
        )
        return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    from baselines.command_line import script_parser  # after OMP_NUM_THREADS is set

    ap = script_parser(__file__, __doc__)
    ap.add_argument("--scenarios", nargs="+", choices=("paper", "random"), default=["paper"])
    ap.add_argument("--steps", type=int, default=300, help="periods played per way")
    ap.add_argument("--worker", choices=WAYS, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.steps < 2:
        ap.error(f"--steps must be at least 2, got {args.steps}")
    if args.worker is not None:
        print(json.dumps(worker(args.worker, args.scenarios[0], args.steps)))
        return
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average before {os.getloadavg()}")  # fmt: skip
    for scenario in args.scenarios:
        results = {way: run(way, scenario, args.steps) for way in WAYS}
        print(f"\n{scenario}: {args.steps} periods")
        print("| library | lines | compile s, whole | compile s, split (units) |")
        print("|---|---|---|---|")
        split = {r["name"]: r for r in results["split"]["compiles"]}
        for row in results["whole"]["compiles"]:
            other = split.get(row["name"], {"seconds": float("nan"), "units": 0})
            print(f"| {row['name']} | {row['lines']:,} | {row['seconds']:.1f} | "
                  f"{other['seconds']:.1f} ({other['units']}) |")  # fmt: skip
        total = {w: sum(r["seconds"] for r in results[w]["compiles"]) for w in WAYS}
        print(f"| all | | {total['whole']:.1f} | {total['split']:.1f} |")
        for key, what in (("decision_ms", "decision median, ms"), ("step_ms", "env step, ms")):
            whole, cut = results["whole"][key], results["split"][key]
            print(f"{what}: whole {whole:.3f}, split {cut:.3f} ({100 * (cut / whole - 1):+.1f} %)")
    print(f"\nload average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
