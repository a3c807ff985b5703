"""Main job: the distributed NMPC expert in closed loop on a scenario, with the paper's
figures, an animation, metrics.json and the trajectory (.npz).

    python -m nmpc_expert --scenario paper --out runs/paper [--solver rti|ipopt]
        [--controller observer|paper] [--seed 0] [--n-agents N] [--object ring|bar]
        [--course open|turns|mixed] [--current none|mild|strong] [--mismatch 0.1]
        [--max-cycles 2000] [--no-figures]

``--controller``: docs/expert.md, "Two controllers". The IPOPT solver runs the paper's
controller only.

One NMPCPolicy per agent on the PettingZoo environment (``uvms_env.parallel_env``), each
fed only its own observation. Every option is checked against the environment's own table
before the controllers are built.

May import: numpy, ``nmpc_expert`` (its ``distributed_episode``, settings and figures) and
``uvms_env`` (the options' tables, the scenario families).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from nmpc_expert.distributed_episode import run_episode
from nmpc_expert.settings import CONTROLLERS, controller_settings
from uvms_env.env.options import ENV_OPTIONS
from uvms_env.scenarios import CURRENT_PRESETS, FAMILIES, make
from uvms_env.scenarios.overrides import SCENARIO_OVERRIDES
from uvms_env.task.metrics import json_ready


def check_options(ap: argparse.ArgumentParser, args: argparse.Namespace, overrides: dict) -> None:
    """Every value against the environment's own table (``ap.error`` naming the flag and
    what it accepts), then the scenario family's own checks (its team size): before the
    controllers are built."""
    values = {"seed": args.seed, "max_cycles": args.max_cycles, **overrides}
    for key, value in values.items():
        option = SCENARIO_OVERRIDES.get(key) or ENV_OPTIONS[key]
        try:
            option.check(f"--{key.replace('_', '-')}", value)
        except (TypeError, ValueError) as exc:
            ap.error(str(exc))
    try:
        make(args.scenario, **overrides)
    except (TypeError, ValueError) as exc:
        ap.error(f"--scenario {args.scenario}: {exc}")


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(
        prog="python -m nmpc_expert",
        description=__doc__.split("May import")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    ap.add_argument("--scenario", default="paper", choices=tuple(FAMILIES))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--n-agents", type=int, default=None, help="team size: random family only (2..8)"
    )
    for key in ("object", "course"):
        option = SCENARIO_OVERRIDES[key]
        ap.add_argument(f"--{key}", default=None, choices=option.choices, help=option.doc)
    ap.add_argument("--current", default="none", choices=CURRENT_PRESETS)
    ap.add_argument("--mismatch", type=float, default=0.0, help="truth-model perturbation")
    ap.add_argument("--solver", default="rti", choices=["rti", "ipopt"])
    ap.add_argument(
        "--controller",
        default=None,
        choices=CONTROLLERS,
        help="observer: offset-free prediction (default with rti); paper: the paper's "
        "controller (default and only choice with ipopt)",
    )
    ap.add_argument("--max-cycles", type=int, default=None, help="episode length cap")
    ap.add_argument("--out", type=Path, default=Path("runs/paper"))
    ap.add_argument("--no-figures", action="store_true", help="no figures, animation, replay")
    args = ap.parse_args(argv)
    overrides: dict = {"current": args.current, "mismatch": args.mismatch}
    for key in ("n_agents", "object", "course"):
        if getattr(args, key) is not None:
            overrides[key] = getattr(args, key)
    controller = args.controller or ("paper" if args.solver == "ipopt" else "observer")
    if controller == "observer" and args.solver == "ipopt":
        ap.error("--controller observer needs --solver rti")
    check_options(ap, args, overrides)
    start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    metrics, arr, scenario = run_episode(
        args.scenario,
        args.solver,
        args.seed,
        args.max_cycles,
        settings=controller_settings(controller),
        replay=None if args.no_figures else args.out / "replay.html",
        **overrides,
    )
    metrics["controller"] = controller
    metrics["wall_time_s"] = time.perf_counter() - start
    np.savez_compressed(args.out / "trajectory.npz", **arr)
    if not args.no_figures:
        from nmpc_expert.figures import make_figures

        print("writing the figures and the animation ...", file=sys.stderr, flush=True)
        make_figures(arr, scenario, args.out)
    metrics["wall_time_incl_figures_s"] = time.perf_counter() - start
    (args.out / "metrics.json").write_text(json.dumps(json_ready(metrics), indent=2))
    for k, v in metrics.items():
        print(f"{k:>28}: {v}")
    print(f"wrote {args.out}")
    return metrics


if __name__ == "__main__":
    main()
