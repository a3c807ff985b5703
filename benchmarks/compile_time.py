"""First-use compile time of the libraries the main job builds, what the evaluator's first
ring episode compiles after it, and the expert's decision time, for this checkout and
(``--compare PATH``) another one, in one run.

    python benchmarks/compile_time.py [--scenarios paper random] [--steps 300]
        [--compare PATH] [--whole]

For each checkout, a fresh process with an empty compile cache (``UVMS_ENV_CACHE``) builds
the paper scenario's environment and one expert per robot and plays ``--steps`` periods
(``paper``: the main job's episode); a second fresh process with the same cache then
plays the evaluator's first ``nmpc`` episode on a ring (``random``: the random family,
N = 2, seed 7). Reported
per library: the generated lines, the units compiled in parallel, the time the compile
announced (``~N s expected``: ``uvms_env.dynamics.compiled.expected_seconds`` from the
cache's log at that moment) and the time it took; per job the total and the median
decision time per robot (the first decision of each robot left out: it holds the
compiles). ``--compare PATH``: another checkout's root (e.g. main's HEAD unpacked with
``git archive``), measured the same way, the checkouts alternating job by job so that a
change of load hits both. ``--whole``: this checkout's C also compiled whole in one unit,
as CasADi writes it (what ``uvms_env.dynamics.split_source``'s cut saves).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parents[1]  # this checkout's root
JOBS = {"paper": ("main job", 0), "random": ("ring episode", 7)}  # scenario: (job, seed)


def worker(scenario: str, seed: int, steps: int, whole: bool) -> dict:
    """One job in this (fresh) process: compile what it needs, play, time."""
    import numpy as np

    import uvms_env
    import uvms_env.dynamics.compiled as compiled
    from nmpc_expert import make_policy
    from uvms_env.policy import AgentSpec

    if whole:  # the generated C as CasADi writes it, one unit
        compiled.cut_long_functions = lambda source: source  # type: ignore[assignment]
        compiled.default_units = lambda source: 1  # type: ignore[assignment]
    log = compiled.cache_dir() / "compile_log.jsonl"
    before = len(log.read_text().splitlines()) if log.exists() else 0
    start = time.perf_counter()
    env = uvms_env.parallel_env(scenario=scenario, seed=seed)
    obs, _ = env.reset(seed=0)
    factory = make_policy("rti", None)
    pols = {a: factory(AgentSpec.from_scenario(env.scenario, i)) for i, a in enumerate(env.agents)}
    decide = []
    for _ in range(steps):
        actions = {}
        for a, p in pols.items():
            t = time.perf_counter()
            actions[a] = p.act(obs[a])
            decide.append(time.perf_counter() - t)
        obs, _, term, trunc, _ = env.step(actions)
        if any(term.values()) or any(trunc.values()):
            break
    rows = [json.loads(r) for r in log.read_text().splitlines()] if log.exists() else []
    return {
        "compiles": rows[before:],
        "earlier": rows[:before],
        "decision_ms": 1e3 * float(np.median(decide[len(pols) :])),
        "seconds_per_line": compiled.SECONDS_PER_LINE,  # this checkout's first guess
        "wall_s": time.perf_counter() - start,
    }


def announced(rows: list[dict], earlier: list[dict], default: float) -> list[float]:
    """What each compile announced: ``expected_seconds``'s rate from the log's last 50
    rows before it (``default``, the checkout's ``SECONDS_PER_LINE``, with none), per line
    and unit."""
    out, log = [], list(earlier)
    for row in rows:
        last = log[-50:]
        lines = sum(r["lines"] for r in last)
        rate = sum(r["seconds"] * r["units"] for r in last) / lines if lines else default
        out.append(rate * row["lines"] / max(1, row["units"]))
        log.append(row)
    return out


def run(checkout: Path, cache: str, scenario: str, steps: int, whole: bool) -> dict:
    _, seed = JOBS[scenario]
    env = {**os.environ, "UVMS_ENV_CACHE": cache, "PYTHONPATH": str(checkout)}
    cmd = [sys.executable, __file__, "--worker", scenario, str(seed), "--steps", str(steps)]
    cmd += ["--whole"] if whole else []
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    from baselines.command_line import script_parser  # after OMP_NUM_THREADS is set

    ap = script_parser(__file__, __doc__)
    ap.add_argument("--scenarios", nargs="+", choices=list(JOBS), default=list(JOBS))
    ap.add_argument("--steps", type=int, default=300, help="periods played per job")
    ap.add_argument("--compare", type=Path, default=None, help="another checkout's root")
    ap.add_argument("--whole", action="store_true", help="this checkout compiled whole too")
    ap.add_argument("--worker", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.steps < 2:
        ap.error(f"--steps must be at least 2, got {args.steps}")
    if args.worker is not None:
        scenario, seed = args.worker
        print(json.dumps(worker(scenario, int(seed), args.steps, args.whole)))
        return
    if args.compare is not None and not (args.compare / "nmpc_expert").is_dir():
        ap.error(f"--compare {args.compare}: not a checkout (no nmpc_expert folder there)")
    from uvms_env.dynamics.compiled import machine_description

    print(f"{machine_description()}; load average before {os.getloadavg()}")
    ways = [("this", HERE, False)]
    ways += [("compared", args.compare, False)] if args.compare else []
    ways += [("this, whole", HERE, True)] if args.whole else []
    caches = {name: tempfile.mkdtemp(prefix="uvms_compile_") for name, _, _ in ways}
    results: dict[str, dict[str, dict]] = {name: {} for name, _, _ in ways}
    for scenario in args.scenarios:  # the ways alternate job by job
        for name, root, whole in ways:
            job = JOBS[scenario][0]
            results[name][job] = run(root, caches[name], scenario, args.steps, whole)
    print("\n| checkout | job | library | lines | units | announced s | compile s |")
    print("|---|---|---|---|---|---|---|")
    for name, _, _ in ways:
        for job, res in results[name].items():
            rows = res["compiles"]
            said_all = announced(rows, res["earlier"], res["seconds_per_line"])
            for row, said in zip(rows, said_all, strict=True):
                print(
                    f"| {name} | {job} | {row['name']} | {row['lines']:,} | {row['units']} | "
                    f"{said:.1f} | {row['seconds']:.1f} |"
                )
            if not rows:
                print(f"| {name} | {job} | (nothing compiled) | | | | |")
    print("\n| checkout | job | libraries | lines | compile s | decision median ms |")
    print("|---|---|---|---|---|---|")
    for name, _, _ in ways:
        for job, res in results[name].items():
            rows = res["compiles"]
            lines = sum(r["lines"] for r in rows)
            total = sum(r["seconds"] for r in rows)
            print(
                f"| {name} | {job} | {len(rows)} | {lines:,} | {total:.1f} | "
                f"{res['decision_ms']:.3f} |"
            )
    if args.compare and "paper" in args.scenarios:
        mine = sum(r["seconds"] for r in results["this"]["main job"]["compiles"])
        theirs = sum(r["seconds"] for r in results["compared"]["main job"]["compiles"])
        print(f"\nmain job's compile, this over compared: {mine / theirs:.2f}")
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
