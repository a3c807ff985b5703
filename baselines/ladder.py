"""The ladder: every rung from full information to the trivial policies, on the same episodes.

    python -m baselines.ladder --split dev --workers 2 --out runs/ladder_dev
    python -m baselines.ladder --split test --workers 2 --out runs/ladder_test  # once per release

One evaluation of the rungs ``LADDER`` on random rings and bars at N = 2..6 and ``paper``,
on a split of episodes (``baselines.evaluation.splits``: ``dev`` for tuning and
selection, ``test`` played once per release of the tables) or on ``--seed``'s; with
``--beyond``, on the cases beyond the training conditions instead (rings and bars of 7 and
8 robots, at the split's counts for them); then the
main table (what each rung was trained on, clean success and success per group of
cases, the graded excess, the return, the paired test against the expert), the per-case
table and the paired comparisons (``baselines.evaluation.ladder_tables``).
``--from EPISODES_CSV`` aggregates earlier runs instead of playing. The talking expert
(``nmpc:comm``) plays the same episodes over an acoustic channel (``--comm``, default
``atm900``); every other rung plays without one (the channel changes no physics draw).
Reference: docs/evaluation.md, docs/results.md.

May import: the standard library, numpy, ``baselines.evaluation``, ``baselines.loaders.sources``
(the model cards, the talking option), ``baselines.command_line``, ``baselines.stats`` and
``uvms_env.robot.channel`` (its presets).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from baselines.command_line import (
    CURRENT_PRESETS,
    add_batch_argument,
    command_parser,
    existing_path,
    model_mismatch,
    non_negative_int,
    positive_int,
    team_size,
    usage_errors,
)
from baselines.evaluation.ladder_tables import (
    CENTRAL,
    EXPERT,
    case_order,
    fmt,
    interval,
    ladder,
    markdown,
    plot_metrics,
    rung_summary,
)
from baselines.evaluation.outputs import read_episodes, run_and_write, write_result
from baselines.evaluation.paired import PAIRED_METRICS, compare
from baselines.evaluation.runner import Case, Settings, UsageError
from baselines.evaluation.splits import SPLITS, add_split_arguments
from baselines.loaders.sources import TALK_OPTION, PolicySource, nmpc_options
from uvms_env.robot.channel import PRESETS

__all__ = ["CENTRAL", "EXPERT", "PRICED", "case_order", "fmt", "interval", "price", "rung_summary"]

TALKER = f"nmpc:{TALK_OPTION}"  # the distributed expert that talks over the channel
# rungs, top (most information) to bottom; the learned ones with and without the filter
LADDER = (
    CENTRAL,  # the full-information reference: one controller for the team, global state
    EXPERT,  # the distributed expert with its disturbance observer (default)
    TALKER,  # the distributed expert talking over the acoustic channel (``--comm``)
    "nmpc:paper",  # the paper's controller
    "dagger:mix",  # DAgger over rings and bars, more two-robot bars; the paper held out
    "dagger:mix+filter",
    "ppo:scratch",  # PPO-Lagrangian from scratch over the distribution, 10M robot-steps
    "ppo:scratch+filter",
    "dagger:pretrained",  # superseded by dagger:mix (trained before bars were in)
    "dagger:pretrained+filter",
    "ppo:pretrained",  # PPO-Lagrangian fine-tuned from the DAgger clone (no bars)
    "ppo:pretrained+filter",
    "student:pretrained",  # DAgger from the reference's decisions (a privileged teacher)
    "student:pretrained+filter",
    "student:expert",  # the same recipe and budget with the distributed expert as teacher
    "student:expert+filter",
    "prior",  # the residual priors with a zero residual: a_ss and the joint hold
    "zero",
    "random",
)
TEAM_SIZES = (2, 3, 4, 5, 6)
# team sizes no learned rung trained on: the random family's largest (``--beyond``)
BEYOND_TEAM_SIZES = (7, 8)
CONDITIONS = {"current": "mild", "mismatch": 0.1}
# what a price compares: name -> the row's key (``baselines.evaluation.paired``)
PRICED = PAIRED_METRICS
DEFAULT_SEED, DEFAULT_EPISODES = SPLITS["dev"].seed, 10
# the talking rungs' channel: the atm900 modem's rate and latency, the preset
# docs/channel.md measures
TALKING_CHANNEL = "atm900"


def talks(policy: str) -> bool:
    """Whether ``policy`` is a talking expert (``nmpc:comm[,...]``), which needs a channel."""
    name, _, options = policy.partition(":")
    return name == "nmpc" and TALK_OPTION in nmpc_options(options)


def with_channel(chosen: list[Case], comm: str) -> list[Case]:
    """The cases with the channel ``comm``: the same labels and episodes."""
    return [Case(c.label, c.scenario, (*c.overrides, ("comm", comm))) for c in chosen]


def price(rows: list[dict[str, Any]], rung: str, reference: str, case: str, seed: int) -> dict:
    """``rung`` against ``reference`` on ``case``'s paired episodes (``paired.compare``)."""
    return compare(rows, rung, reference, case, seed)


# the bar cases' options: the random family's bars on courses that turn around obstacles
# or not, drawn per episode (docs/options.md, "Bars and turning courses")
BAR_CASE = (("object", "bar"), ("course", "mixed"))


def cases(
    team_sizes: tuple[int, ...] = TEAM_SIZES,
    paper: bool = True,
    bars: bool = True,
    rings: bool = True,
) -> list[Case]:
    """The ladder's cases: (``rings``) random rings at each team size, then (``bars``)
    random bars, then (``paper``) the paper's scenario."""
    out = [Case(f"random N={n}", "random", (("n_agents", n),)) for n in team_sizes if rings]
    if bars:
        out += [
            Case(f"random bar N={n}", "random", (("n_agents", n), *BAR_CASE)) for n in team_sizes
        ]
    return [*out, Case("paper", "paper")] if paper else out


def trained_on(policy: str) -> str:
    """What ``policy`` was trained on, from its model card (``PolicySource.card``):
    whether ``paper`` and the bars were in its training, its budget and seeds; "" for a
    controller or a trivial rung."""
    try:
        card = PolicySource.parse(policy).card()
    except ValueError:
        return ""
    if not card or "trained_on" not in card:
        return ""
    t = card["trained_on"]
    yes = {True: "in", False: "out"}
    return f"paper {yes[t['paper']]}, bars {yes[t['bars']]}; {t['budget']}; {t['seeds']} seeds"


def write(result: dict[str, Any], command: dict[str, Any], out: Path) -> None:
    """``ladder.json`` (with ``command``), ``ladder.md`` and one figure per metric against
    N (``ladder_*_vs_n.png``) in ``out``."""
    policies = list(dict.fromkeys(s["policy"] for s in result["rungs"]))
    trained = {p: trained_on(p) for p in policies}
    write_result(out, "ladder", result, markdown(result, trained), command)
    plot_metrics(result, out)


def merged(paths: list[Path], seed: int, out: Path) -> dict[str, Any]:
    """The ladder of several runs' episodes (the same cases and seed, e.g. the expert
    rungs run apart from the learned ones: each rung plays the same seeded episodes
    whatever else runs beside it), rungs in ``LADDER`` order, then any others."""
    rows = [r for p in paths for r in read_episodes(p)]
    present = list(dict.fromkeys(r["policy"] for r in rows))
    policies = [p for p in LADDER if p in present] + [p for p in present if p not in LADDER]
    labels = list(dict.fromkeys(r["scenario"] for r in rows))
    result = ladder(rows, policies, labels, seed)
    write(result, {"merged": [str(p) for p in paths], "seed": seed}, out)
    return result


def run(
    policies: list[str],
    chosen: list[Case],
    settings: Settings,
    out: Path,
    comm: str = TALKING_CHANNEL,
) -> dict[str, Any]:
    """Evaluate the rungs on the cases (the talking ones over the channel ``comm``), write
    every output, return the ladder."""
    talking = [p for p in policies if talks(p)]
    silent = [p for p in policies if not talks(p)]
    plays = [(silent, chosen)] if silent else []
    if talking:
        plays.append((talking, with_channel(chosen, comm)))
    rows, _ = run_and_write(settings, plays, out)
    result = ladder(rows, policies, [c.label for c in chosen], settings.seed)
    record = settings.record()
    if talking:
        record["talking_channel"] = comm
    write(result, record, out)
    return result


def add_case_arguments(
    ap: argparse.ArgumentParser, team_sizes: tuple[int, ...], out: str, bars: bool = True
) -> None:
    """The cases, conditions and run options the ladder and the channel sweep share;
    ``bars``: whether the bar cases are in by default (``--no-bars``) or out (``--bars``)."""
    ap.add_argument(
        "--n-agents",
        type=team_size,
        nargs="+",
        default=None,
        help=f"random team sizes (default {' '.join(map(str, team_sizes))}; with --beyond "
        f"{' '.join(map(str, BEYOND_TEAM_SIZES))})",
    )
    ap.add_argument(
        "--beyond",
        action="store_true",
        help="the cases beyond the training conditions: rings and bars of "
        f"{' and '.join(map(str, BEYOND_TEAM_SIZES))} robots, no paper, at the split's "
        "counts for them",
    )
    ap.set_defaults(team_sizes=team_sizes)
    ap.add_argument("--no-paper", action="store_true", help="leave the paper scenario out")
    ap.add_argument("--no-rings", action="store_true", help="leave the ring cases out")
    if bars:
        ap.add_argument(
            "--no-bars", dest="bars", action="store_false", help="leave the bar cases out"
        )
    else:
        ap.add_argument("--bars", action="store_true", help="add the bar cases")
    add_split_arguments(ap, non_negative_int, positive_int, DEFAULT_SEED)
    ap.add_argument("--workers", type=positive_int, default=2)
    add_batch_argument(ap)
    ap.add_argument("--current", default=CONDITIONS["current"], choices=CURRENT_PRESETS)
    ap.add_argument("--mismatch", type=model_mismatch, default=CONDITIONS["mismatch"])
    ap.add_argument("--max-cycles", type=positive_int, default=None)
    ap.add_argument("--out", type=Path, default=Path(out))


def settings_of(args: argparse.Namespace) -> Settings:
    """The evaluation settings of ``add_case_arguments``' flags: a split (its seed and
    counts), or ``--seed`` (default dev's) and ``--episodes`` (default 10)."""
    conditions = {"current": args.current, "mismatch": args.mismatch}
    return Settings.of_args(
        args,
        DEFAULT_SEED,
        DEFAULT_EPISODES,
        workers=args.workers,
        conditions=conditions,
        max_cycles=args.max_cycles,
        batch=args.batch,
        beyond=args.beyond,
    )


def cases_of(args: argparse.Namespace) -> list[Case]:
    """The cases of ``add_case_arguments``' flags (``--beyond``: its team sizes, no paper)."""
    sizes = tuple(args.n_agents or (BEYOND_TEAM_SIZES if args.beyond else args.team_sizes))
    if args.beyond and not set(sizes) <= set(BEYOND_TEAM_SIZES):
        raise UsageError(f"--beyond plays team sizes {BEYOND_TEAM_SIZES}, not {list(sizes)}")
    paper = not (args.no_paper or args.beyond)
    chosen = cases(sizes, paper, args.bars, not args.no_rings)
    if not chosen:
        raise UsageError("no case left: --no-rings, --no-paper and no bar cases")
    return chosen


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.ladder", __doc__)
    ap.add_argument("--policy", action="append", default=None, help=f"rungs (default {LADDER})")
    ap.add_argument(
        "--from",
        dest="sources",
        action="append",
        type=existing_path,
        default=None,
        metavar="EPISODES_CSV",
        help="no evaluation: the ladder of these runs' episodes.csv together (same seed or split)",
    )
    add_case_arguments(ap, TEAM_SIZES, "runs/ladder")
    ap.add_argument(
        "--comm",
        default=TALKING_CHANNEL,
        choices=sorted(PRESETS),
        metavar="PRESET",
        help=f"the talking rungs' (nmpc:comm) acoustic channel (default {TALKING_CHANNEL}; "
        f"presets: {', '.join(sorted(PRESETS))}); the other rungs play without one",
    )
    args = ap.parse_args(argv)
    settings = settings_of(args)
    if args.sources:
        merged(args.sources, settings.seed, args.out)
        print((args.out / "ladder.md").read_text())
        print(f"wrote {args.out}/ladder.md, ladder.json and the figures against N")
        return
    policies = args.policy or list(LADDER)
    # a rung that cannot be loaded, a case the environment refuses: before any episode
    with usage_errors(ap, (UsageError,)):
        run(policies, cases_of(args), settings, args.out, args.comm)
    print((args.out / "ladder.md").read_text())
    print(f"wrote {args.out}/ladder.md, ladder.json, the figures and the evaluator's outputs")


if __name__ == "__main__":
    main()
