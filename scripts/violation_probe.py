"""Where, which joint and by how much: every violation period of policies on seeded episodes.

    python scripts/violation_probe.py --policy nmpc --policy nmpc:central \\
        --scenario random --n-agents 6 --episodes 3 --seed 202

Plays the evaluator's episodes (``baselines.evaluation.runner.case_episode_seed``: the same
seeds as ``python -m baselines.evaluate`` with the same arguments) and prints one line per robot
and period with a violated constraint: the period, the waypoint the team heads to, the
kind, by how much, for ``joint_speed`` which joint and its rate, and the robot's decision
(the expert's status, its margin ``margin_max`` and predicted rate offset) and in how
many of the last ``WINDOW`` periods the robot had a saturated input. A summary per
policy and episode follows. Why: the rare violation periods of the distributed expert
at large N need their place in the episode and their cause, with the full-information reference
beside them on the same episodes.

An analysis script, not part of the installed packages.
May import: numpy, ``uvms_env`` and ``baselines``.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

import uvms_env
from baselines.evaluation.runner import case_episode_seed
from baselines.loaders.sources import PolicySource
from uvms_env.env.infos import constraint_kinds
from uvms_env.episode import Step, play, play_team

SATURATED = 0.98  # |a| at which a normalized input counts as saturated
WINDOW = 10  # periods before a violation in which saturated inputs are counted


def probe(policy: str, scenario: str, seed: int, overrides: dict[str, Any]) -> list[dict]:
    """The violation periods of one episode, one dict per robot and period."""
    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **overrides)
    source = PolicySource.parse(policy)
    found: list[dict] = []
    switches: list[int] = []  # periods at which the team's waypoint changed
    heading = [None]
    recent: dict[str, list[bool]] = {}  # per robot: had a saturated input, last periods

    def on_step(step: Step) -> None:
        sim = step.env.unwrapped.sim
        waypoint = tuple(np.round(step.env.unwrapped.state()[-7:-1], 6))
        if heading[0] is not None and waypoint != heading[0]:
            switches.append(step.index)
        heading[0] = waypoint
        for i, (agent, info) in enumerate(step.infos.items()):
            action = np.asarray(step.actions[agent][:8]) if agent in step.actions else None
            window = recent.setdefault(agent, [])
            if action is not None:
                window.append(bool(np.abs(action).max() >= SATURATED))
                del window[:-WINDOW]
            for kind in constraint_kinds(info):
                value = info[f"constraint_{kind}"]
                if value <= 0:
                    continue
                row = {"period": step.index, "robot": i, "kind": kind, "excess": value}
                stats = step.policies.get(agent, step.policies.get("team")).stats
                row["waypoint"] = stats.get("waypoint_index")
                row["saturated_periods"] = sum(window)  # of the last WINDOW
                row["status"] = stats.get("status")
                if kind == "joint_speed":
                    rates = np.asarray(sim.state.zeta[i][6:10])
                    row["joint"] = int(np.argmax(np.abs(rates)))
                    row["rate"] = float(rates[row["joint"]])
                for key in ("margin_max", "rate_offset_max", "disturbance_max", "slack_max"):
                    if key in stats:
                        row[key] = float(stats[key])
                found.append(row)

    if source.team:
        episode = play_team(env, source.team_factory(seed), seed, on_step=on_step)
    else:
        episode = play(env, source.factory(seed), seed, on_step=on_step)
    env.close()
    end = {k: episode.metrics[k] for k in ("success", "episode_steps")}
    found.append({"summary": True, "switches": switches, **end})
    return found


def main() -> None:
    ap = argparse.ArgumentParser(
        prog="python scripts/violation_probe.py",
        description=__doc__,
        formatter_class=argparse.RawTextHelpFormatter,
        allow_abbrev=False,
    )
    ap.add_argument("--policy", action="append", required=True)
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--n-agents", type=int, default=None)
    ap.add_argument("--current", default=None)
    ap.add_argument("--mismatch", type=float, default=None)
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--first", type=int, default=0, help="first episode index")
    ap.add_argument("--seed", type=int, default=202)
    args = ap.parse_args()
    overrides = {
        k: v
        for k, v in (
            ("n_agents", args.n_agents),
            ("current", args.current),
            ("mismatch", args.mismatch),
        )
        if v is not None
    }
    for k in range(args.first, args.first + args.episodes):
        seed = case_episode_seed(args.seed, args.scenario, k)
        for policy in args.policy:
            rows = probe(policy, args.scenario, seed, overrides)
            end = rows.pop()
            print(
                f"== {policy} episode {k} (seed {seed}): success {end['success']}, "
                f"{end['episode_steps']} periods, {len(rows)} robot-periods violated; "
                f"waypoint switches at {end['switches']}"
            )
            for r in rows:
                extra = " ".join(
                    f"{key}={r[key]:.4g}" if isinstance(r[key], float) else f"{key}={r[key]}"
                    for key in r
                    if key not in ("period", "robot", "kind", "excess")
                )
                print(
                    f"  t={r['period']:5d} robot {r['robot']} {r['kind']:<14} "
                    f"+{r['excess']:.4f} {extra}"
                )


if __name__ == "__main__":
    main()
