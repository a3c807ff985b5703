"""One fair comparison of policies on the same seeded episodes.

    python -m baselines.evaluate --policy nmpc --policy random --scenario paper \\
        --scenario random --episodes 20 --seed 0 --workers 2 --out runs/eval
    python -m baselines.evaluate --policy nmpc --scenario paper --split dev --out runs/dev

Every policy plays exactly the same episodes, and a result depends only on (policy,
scenario, seed), never on the number of workers. Outputs and policies: docs/evaluation.md.

May import: the standard library, ``baselines.evaluation``, ``baselines.command_line`` and
``baselines.evaluation.marl_eval``. The command line only: the evaluator's parts live in
``baselines.evaluation``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from baselines.command_line import (
    SCENARIOS,
    add_batch_argument,
    add_condition_arguments,
    command_parser,
    non_negative_int,
    positive_int,
    usage_errors,
)
from baselines.evaluation.outputs import run_and_write
from baselines.evaluation.report import markdown_table
from baselines.evaluation.runner import BACKENDS, Settings, UsageError
from baselines.evaluation.splits import add_split_arguments


def build_parser() -> argparse.ArgumentParser:
    """The evaluator's command line."""
    ap = command_parser("baselines.evaluate", __doc__)
    ap.add_argument(
        "--policy",
        action="append",
        required=True,
        help="nmpc, random, zero, prior, ppo:PATH, sac:PATH, rllib:PATH, bc:PATH, dagger:PATH, "
        "pkg.mod:factory; suffix +filter: inside the expert's safety filter; nmpc:central: "
        "the full-information reference, a team policy on the global state (its rows say "
        "information full: a reference, not a decentralized entry; it bounds nothing)",
    )
    ap.add_argument(
        "--scenario",
        action="append",
        choices=SCENARIOS,
        default=None,
        help="paper, random, short (repeatable; default paper)",
    )
    add_split_arguments(ap, non_negative_int, positive_int, default_seed=0)
    ap.add_argument("--workers", type=positive_int, default=2)
    add_batch_argument(ap)
    ap.add_argument("--max-cycles", type=positive_int, default=None)
    add_condition_arguments(ap, draws=False)  # the trainers' flags, one value each
    ap.add_argument(
        "--comm",
        default=None,
        metavar="PRESET",
        help="acoustic channel preset (uvms_env.robot.channel.PRESETS; default off): policies "
        "that do not read messages play silent",
    )
    for flag, what in (("reward-term", "reward term"), ("constraint", "constraint")):
        ap.add_argument(
            f"--extra-{flag}",
            action="append",
            default=[],
            metavar="NAME=MODULE:FUNCTION",
            help=f"an extra {what} fn(s, xp) of the environment (uvms_env.task.rules)",
        )
    ap.add_argument("--out", type=Path, default=Path("runs/eval"))
    ap.add_argument(
        "--replay",
        action="store_true",
        help="also write a 3D replay page of each policy's first episode per scenario to --out",
    )
    ap.add_argument(
        "--backend",
        choices=BACKENDS,
        default="process",
        help="process: a process pool of --workers; ray: Ray tasks (pip install -e "
        '".[distributed]"), on a local Ray of --workers CPUs or the cluster at --address',
    )
    ap.add_argument("--address", default=None, help="Ray cluster to join (--backend ray)")
    ap.add_argument(
        "--marl-eval-json",
        type=Path,
        default=None,
        metavar="PATH",
        help="also write (merge into) marl-eval's JSON: env uvms (BenchMARL's name), task = "
        "scenario, algorithm and seed_S = what trained the policy (its run's config.json; "
        "baselines.evaluation.marl_eval)",
    )
    ap.add_argument(
        "--marl-eval-step-count",
        type=non_negative_int,
        default=0,
        help="the step_count recorded in the marl-eval JSON (e.g. the policy's training steps)",
    )
    return ap


def env_overrides(ap: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, Any]:
    """The environment keywords of the command line (``ap.error`` on a malformed one)."""
    names = ("n_agents", "object", "course", "current", "mismatch", "comm")
    overrides = {k: v for k in names if (v := getattr(args, k)) is not None}
    for key in ("extra_reward_terms", "extra_constraints"):
        if given := getattr(args, key[:-1]):  # --extra-reward-term, --extra-constraint
            if not all("=" in g for g in given):
                ap.error(f"--{key.replace('_', '-')[:-1]}: expected NAME=MODULE:FUNCTION")
            overrides[key] = dict(g.split("=", 1) for g in given)
    return overrides


def main(argv: list[str] | None = None) -> None:
    """Evaluate, write the outputs (and marl-eval's JSON on request), print the table."""
    ap = build_parser()
    args = ap.parse_args(argv)
    overrides = env_overrides(ap, args)
    settings = Settings.of_args(
        args,
        0,
        20,
        workers=args.workers,
        conditions=overrides,
        max_cycles=args.max_cycles,
        backend=args.backend,
        address=args.address,
        replay_dir=args.out if args.replay else None,
        batch=args.batch,
    )
    # a policy that cannot be loaded, a case the environment refuses: before any episode
    with usage_errors(ap, (UsageError,)):
        rows, summaries = run_and_write(
            settings, [(args.policy, args.scenario or ["paper"])], args.out
        )
    if args.marl_eval_json is not None:
        from baselines.evaluation import marl_eval

        marl_eval.write(
            args.marl_eval_json,
            rows,
            settings.seed,
            step_count=args.marl_eval_step_count,
            overrides=overrides,
        )
        print(f"wrote {args.marl_eval_json} (marl-eval)")
    print(markdown_table(summaries))
    print(f"wrote {args.out}/episodes.csv, results.json, results.md and plots")


if __name__ == "__main__":
    main()
