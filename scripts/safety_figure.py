"""The safety filter's figure: a policy's joint rates with and without the filter.

    python scripts/safety_figure.py --policy dagger:pretrained --scenario random \\
        --n-agents 2 --seed 7 --episode 3 --out docs/figures/safety_filter_joint_rates.png

Plays episode ``--episode`` of the evaluator's seeding (``baselines.evaluate``) twice,
with ``POLICY`` and with ``POLICY+filter``, and plots per period the largest joint rate
of any robot (true state) against the limit and the filter's tightened bound, and the
largest joint angle against its limit (both axes clipped at 3x and 2x the limit).

An analysis script, not part of the installed packages.
May import: numpy, matplotlib, ``uvms_env``, ``nmpc_expert`` and ``baselines``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

import uvms_env
from baselines.evaluation.runner import case_episode_seed
from baselines.loaders.sources import PolicySource
from uvms_env.episode import Step, play


def joint_trace(policy: str, scenario: str, seed: int, overrides: dict) -> dict[str, Any]:
    """Per period: largest |joint rate| and |joint angle| over robots, and metrics."""
    rates: list[float] = []
    angles: list[float] = []

    def record(step: Step) -> None:
        state = step.env.unwrapped.sim.state
        rates.append(float(np.abs(state.zeta[:, 6:]).max()))
        angles.append(float(np.abs(state.q[:, 6:]).max()))

    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **overrides)
    episode = play(env, PolicySource.parse(policy).factory(seed), seed, on_step=record)
    return {"rate": np.array(rates), "angle": np.array(angles), "metrics": episode.metrics}


def main(argv: list[str] | None = None) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    ap = argparse.ArgumentParser(
        prog="python scripts/safety_figure.py",
        description=__doc__.split("\n\n")[0],
        allow_abbrev=False,
    )
    ap.add_argument("--policy", default="dagger:pretrained")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--n-agents", type=int, default=2)
    ap.add_argument("--seed", type=int, default=7, help="evaluation seed")
    ap.add_argument("--episode", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("docs/figures/safety_filter_joint_rates.png"))
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nmpc_expert import NMPCSettings

    overrides = {"n_agents": args.n_agents} if args.scenario == "random" else {}
    seed = case_episode_seed(args.seed, args.scenario, args.episode)
    s = NMPCSettings()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 4.2), sharex=True)
    for k, policy in enumerate((args.policy, args.policy + "+filter")):
        tr = joint_trace(policy, args.scenario, seed, overrides)
        m = tr["metrics"]
        t = s.period * np.arange(1, len(tr["rate"]) + 1)
        outcome = "success" if m["success"] else "failure"
        label = f"{policy}: {outcome}, {m['violation_periods']} violation periods"
        top.plot(t, tr["rate"], color=f"C{k}", lw=0.8, label=label)
        bottom.plot(t, tr["angle"], color=f"C{k}", lw=0.8)
        print(label)
    top.axhline(s.joint_speed, color="k", ls="--", lw=0.8, label="limit")
    top.axhline(s.angular_backoff * s.joint_speed, color="k", ls=":", lw=0.8, label="filter bound")
    top.set_ylim(0, 3 * s.joint_speed)  # clipped: the unfiltered policy goes far beyond
    top.set_ylabel("max |joint rate| [rad/s]")
    top.legend(fontsize=7, loc="upper right")
    bottom.axhline(s.joint_position, color="k", ls="--", lw=0.8)
    bottom.axhline(s.backoff * s.joint_position, color="k", ls=":", lw=0.8)
    bottom.set_ylim(0, 2 * s.joint_position)
    bottom.set_ylabel("max |joint angle| [rad]")
    bottom.set_xlabel("time [s]")
    top.set_title(f"{args.scenario} N = {args.n_agents}, seed {args.seed}, episode {args.episode}")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
