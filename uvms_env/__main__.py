"""Passive demo of the truth simulator: hold the paper scenario's start for a while.

    python -m uvms_env --scenario paper --seconds 30 --out runs/sim_demo

Applies the static holding inputs (a feed-forward, no feedback: the equilibrium is not
stable under constant inputs) and writes ``summary.json``: grasp drift, object motion,
energy, speed. A smoke test of the physics without any controller; the main job with
a controller is ``python -m nmpc_expert``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from uvms_env.scenarios import make
from uvms_env.sim import Simulator


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenario", default="paper", help="scenario family (paper, random)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-agents", type=int, default=None, help="random family only")
    ap.add_argument("--current", default="none", choices=["none", "mild", "strong"])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--out", type=Path, default=Path("runs/sim_demo"))
    args = ap.parse_args()
    overrides = {"seed": args.seed, "current": args.current}
    if args.n_agents is not None:
        overrides["n_agents"] = args.n_agents
    scenario = make(args.scenario, **overrides)
    sim = Simulator(scenario)
    tau = sim.holding_inputs()
    e0, drift, steps = sim.energy(), 0.0, round(args.seconds / scenario.period)
    start = time.perf_counter()
    for _ in tqdm(range(steps), desc=f"{args.scenario}: holding", unit="period"):
        sim.step(tau)
        drift = max(drift, float(sim.grasp_error()[0].max()))
    wall = time.perf_counter() - start
    st = sim.state
    summary = {
        "scenario": args.scenario,
        "n_agents": scenario.n_agents,
        "sim_time_s": round(st.t, 3),
        "holding_inputs": tau.round(4).tolist(),
        "object_start": scenario.object_start.tolist(),
        "object_final": st.x_O.round(4).tolist(),
        "object_displacement_m": float(np.linalg.norm(st.x_O[:3] - scenario.object_start[:3])),
        "grasp_drift_max_m": drift,
        "energy_change_J": sim.energy() - e0,
        "periods_per_second_incl_diagnostics": steps / wall,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    for key, value in summary.items():
        if key != "holding_inputs":
            print(f"{key:>36}: {value}")
    print(f"wrote {args.out / 'summary.json'}")


if __name__ == "__main__":
    main()
