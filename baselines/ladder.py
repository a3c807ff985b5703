"""The ladder: every rung from full information to learned policies, on the same episodes.

    python -m baselines.ladder --episodes 10 --seed 202 --workers 2 --out runs/ladder

One evaluation of the rungs ``LADDER`` on random rings and bars at N = 2..6 and ``paper``,
then per team size the price of decentralization (each distributed expert against
``nmpc:central``) and the price of learning (each learned rung against ``nmpc``, and
against ``nmpc:central``) on the paired episodes.
``--from EPISODES_CSV`` aggregates earlier runs instead of playing.
Reference: docs/evaluation.md, docs/results.md.

May import: the standard library, numpy, ``baselines.evaluation``, ``baselines.command_line`` and
``baselines.stats``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from baselines.command_line import (
    CURRENT_PRESETS,
    command_parser,
    existing_path,
    model_mismatch,
    non_negative_int,
    positive_int,
    team_size,
    usage_errors,
)
from baselines.evaluation.outputs import read_episodes, run_and_write, write_result
from baselines.evaluation.report import pyplot, save, table
from baselines.evaluation.runner import Case, Settings, UsageError
from baselines.evaluation.summary import groups, metric_values, summarize
from baselines.stats import bootstrap_mean_interval

CENTRAL = "nmpc:central"
EXPERT = "nmpc"
# rungs, top (most information) to bottom; the learned ones with and without the filter
LADDER = (
    CENTRAL,
    EXPERT,  # the distributed expert with its disturbance observer (default)
    "nmpc:paper",  # the paper's controller
    "dagger:pretrained",
    "dagger:pretrained+filter",
    "ppo:pretrained",  # PPO-Lagrangian fine-tuned from the DAgger clone
    "ppo:pretrained+filter",
    "student:pretrained",  # DAgger from the bound's decisions (a privileged teacher)
    "student:pretrained+filter",
    "student:expert",  # the same recipe and budget with the distributed expert as teacher
    "student:expert+filter",
    "ppo:scratch",  # MAPPO from scratch over the distribution (rings and bars), with the priors
    "ppo:scratch+filter",
    "dagger:mix",  # DAgger over rings and bars, more two-robot bars; the paper held out
    "dagger:mix+filter",
)
TEAM_SIZES = (2, 3, 4, 5, 6)
CONDITIONS = {"current": "mild", "mismatch": 0.1}
# what a price compares: per-episode metric -> the row's key
PRICED = {
    "completion periods": "completion_periods",
    "internal wrench rms": "internal_wrench_rms",
    "control effort": "control_effort",
}


# the figure's line style per kind of price
PRICE_STYLES = {"decentralization": "-o", "learning": "--s", "learning against the bound": ":^"}
# a price's point in the figure needs this many paired successes (fewer: noise)
MIN_PAIRED = 3


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


def rung_summary(rows: list[dict[str, Any]], seed: int) -> dict[str, Any]:
    """One rung on one case: ``summarize`` over the episodes within reach (completion
    time over the successes), its priced metrics and violation periods, and the decision
    time's median and p95."""
    out = summarize(rows, seed, (*PRICED.values(), "violation_periods"), within_reach_only=True)
    for key in ("violations", "intervention_rate", "intervention_mean"):
        del out[key]
    times = out.pop("policy_time_ms")
    out["decision_ms_median"], out["decision_ms_p95"] = times["median"], times["p95"]
    return out


def price(
    rows: list[dict[str, Any]], rung: str, reference: str, case: str, seed: int
) -> dict[str, Any]:
    """``rung`` against ``reference`` on ``case``'s paired episodes: per priced metric the
    mean difference (rung minus reference) over the episodes both succeeded in, its
    bootstrap interval, and the ratio of the two means; and the success-rate difference."""
    by = groups(rows)
    mine, ref = ({r["episode"]: r for r in by.get((p, case), [])} for p in (rung, reference))
    reach = [k for k in mine.keys() & ref.keys() if mine[k].get("current_within_reach", True)]
    both = sorted(k for k in reach if mine[k].get("success") and ref[k].get("success"))
    wins = sum(bool(mine[k].get("success")) - bool(ref[k].get("success")) for k in reach)
    out: dict[str, Any] = {
        "rung": rung,
        "reference": reference,
        "scenario": case,
        "paired_successes": len(both),
        "success_difference": wins / len(reach) if reach else None,
    }
    for name, key in PRICED.items():
        a, b = (metric_values([d[k] for k in both], key) for d in (mine, ref))
        ok = np.isfinite(a) & np.isfinite(b)
        if not ok.any():
            out[name] = None
            continue
        diff = a[ok] - b[ok]
        out[name] = {
            "difference": float(diff.mean()),
            "difference_ci95": list(bootstrap_mean_interval(diff, seed=seed)),
            "ratio": float(a[ok].mean() / b[ok].mean()) if b[ok].mean() != 0 else None,
        }
    return out


def ladder(
    rows: list[dict[str, Any]], policies: list[str], labels: list[str], seed: int
) -> dict[str, Any]:
    """The ladder's summaries and prices from the evaluator's rows."""
    by = groups(rows)
    rungs = [rung_summary(by[p, c], seed) for p in policies for c in labels if (p, c) in by]
    distributed = [p for p in policies if p.startswith("nmpc") and p != CENTRAL]
    learned = [p for p in policies if not p.startswith("nmpc")]
    # each kind of price: the rungs it prices and their reference (when it played)
    kinds = {
        "decentralization": (distributed, CENTRAL),
        "learning": (learned, EXPERT),
        "learning against the bound": (learned, CENTRAL),
    }
    prices = {
        kind: [price(rows, p, ref, c, seed) for c in labels for p in priced if ref in policies]
        for kind, (priced, ref) in kinds.items()
    }
    return {"rungs": rungs, "prices": prices}


def fmt(x: Any, digits: int = 2) -> str:
    """A table cell: n/a for None or a non-finite number."""
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "n/a"
    return f"{x:,.{digits}f}" if isinstance(x, float) else str(x)


def case_order(summary: dict[str, Any]) -> tuple[bool, str]:
    """Tables list the cases random N = 2..6 first, then paper."""
    return (summary["scenario"] == "paper", summary["scenario"])


def interval(x: Any, bounds: Any, digits: int = 2) -> str:
    """A table cell: ``x [low, high]``; n/a without ``x``."""
    if x is None:
        return "n/a"
    return f"{fmt(x, digits)} [{fmt(bounds[0], digits)}, {fmt(bounds[1], digits)}]"


def markdown(result: dict[str, Any]) -> str:
    lines = table(
        "scenario | policy | information | success | clean success | completion periods "
        "| internal wrench rms N | control effort | violation periods / ep. mean (median) "
        "| decision ms median / p95"
    )
    # grouped by case, rungs in ladder order within each
    for s in sorted(result["rungs"], key=case_order):
        n = s["episodes"] - s["out_of_reach"]
        rate = interval(f"{s['success']}/{n}", s["success_ci95"]) if n else "n/a"
        clean = f"{s['clean_success']}/{n}" if n else "n/a"
        means = [  # periods and effort in whole numbers, the wrench to 0.01 N
            interval(s.get(k), s.get(f"{k}_ci95"), d)
            for k, d in zip(PRICED.values(), (0, 2, 0), strict=True)
        ]
        lines.append(
            f"| {s['scenario']} | `{s['policy']}` | {s['information']} | {rate} | {clean} | "
            + " | ".join(means)
            + f" | {fmt(s.get('violation_periods'), 1)} "
            f"({fmt(s.get('violation_periods_median'), 0)}) | "
            f"{fmt(s['decision_ms_median'], 3)} / {fmt(s['decision_ms_p95'], 3)} |"
        )
    for kind, rows in result["prices"].items():
        if not rows:
            continue
        lines += [
            "",
            f"Price of {kind} (rung minus reference on the episodes both succeeded in: mean "
            "difference [95% CI], ratio of means):",
            "",
            *table(
                "scenario | rung | reference | paired | success difference | " + " | ".join(PRICED)
            ),
        ]
        for p in rows:
            cells = [
                "n/a"
                if (v := p[name]) is None
                else f"{interval(v['difference'], v['difference_ci95'])}, x{fmt(v['ratio'])}"
                for name in PRICED
            ]
            lines.append(
                f"| {p['scenario']} | `{p['rung']}` | `{p['reference']}` | "
                f"{p['paired_successes']} | {fmt(p['success_difference'])} | "
                + " | ".join(cells)
                + " |"
            )
    return "\n".join(lines) + "\n"


def overview(result: dict[str, Any]) -> str:
    """One row per rung, one column per case: clean successes / successes, then the
    median decision time over every case (the README's table)."""
    labels = list(dict.fromkeys(s["scenario"] for s in result["rungs"]))
    policies = list(dict.fromkeys(s["policy"] for s in result["rungs"]))
    by = {(s["policy"], s["scenario"]): s for s in result["rungs"]}
    head = " | ".join(f"`{c}`" if c == "paper" else c for c in labels)
    lines = table(f"rung | information | {head} | decision ms, median (slowest case)")
    for p in policies:
        mine = [by.get((p, c)) for c in labels]
        cells = [
            f"{s['clean_success']} / {s['success']} / {s['episodes'] - s['out_of_reach']}"
            if s
            else ""
            for s in mine
        ]
        times = [s["decision_ms_median"] for s in mine if s and s["decision_ms_median"] is not None]
        info = mine[0]["information"] if mine[0] else ""
        lines.append(
            f"| `{p}` | {info} | " + " | ".join(cells) + f" | {fmt(max(times, default=None), 2)} |"
        )
    return "\n".join(lines) + "\n"


def plot_prices(result: dict[str, Any], out: Path) -> None:
    """Ratio of means (rung / reference) against the team size, one panel per metric;
    points with fewer than ``MIN_PAIRED`` paired successes are left out."""
    fig, axes = pyplot().subplots(1, len(PRICED), figsize=(4.2 * len(PRICED), 3.4), sharex=True)
    for ax, name in zip(np.atleast_1d(axes), PRICED, strict=True):
        for kind, style in PRICE_STYLES.items():
            by_rung: dict[str, list[tuple[int, float]]] = {}
            for p in result["prices"][kind]:
                v, case = p[name], p["scenario"]
                if not (case.startswith("random N=") and v and v["ratio"] is not None):
                    continue
                if p["paired_successes"] >= MIN_PAIRED:
                    point = (int(case.split("=")[1]), v["ratio"])
                    by_rung.setdefault(f"{p['rung']} / {p['reference']}", []).append(point)
            for label, pts in by_rung.items():
                ax.plot(*zip(*sorted(pts), strict=True), style, label=label)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("robots N (random family)")
        ax.set_ylabel("ratio of means")
    first = np.atleast_1d(axes)[0]
    if first.get_legend_handles_labels()[0]:  # nothing priced (e.g. no success): no legend
        first.legend(fontsize=7)
    save(fig, out / "price_vs_n.png")


def write(result: dict[str, Any], command: dict[str, Any], out: Path) -> None:
    """``ladder.json`` (with ``command``), ``ladder.md`` and ``price_vs_n.png`` in ``out``."""
    write_result(out, "ladder", result, markdown(result) + "\n" + overview(result), command)
    plot_prices(result, out)


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


def run(policies: list[str], chosen: list[Case], settings: Settings, out: Path) -> dict[str, Any]:
    """Evaluate the rungs on the cases, write every output, return the ladder."""
    rows, _ = run_and_write(settings, [(policies, chosen)], out)
    result = ladder(rows, policies, [c.label for c in chosen], settings.seed)
    write(result, settings.record(), out)
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
        default=list(team_sizes),
        help=f"random team sizes (the ladder's: {' '.join(map(str, TEAM_SIZES))})",
    )
    ap.add_argument("--no-paper", action="store_true", help="leave the paper scenario out")
    ap.add_argument("--no-rings", action="store_true", help="leave the ring cases out")
    if bars:
        ap.add_argument(
            "--no-bars", dest="bars", action="store_false", help="leave the bar cases out"
        )
    else:
        ap.add_argument("--bars", action="store_true", help="add the bar cases")
    ap.add_argument("--episodes", type=positive_int, default=10)
    ap.add_argument(
        "--seed", type=non_negative_int, default=202, help="held out: used by no training"
    )
    ap.add_argument("--workers", type=positive_int, default=2)
    ap.add_argument("--current", default=CONDITIONS["current"], choices=CURRENT_PRESETS)
    ap.add_argument("--mismatch", type=model_mismatch, default=CONDITIONS["mismatch"])
    ap.add_argument("--max-cycles", type=positive_int, default=None)
    ap.add_argument("--out", type=Path, default=Path(out))


def settings_of(args: argparse.Namespace) -> Settings:
    """The evaluation settings of ``add_case_arguments``' flags."""
    conditions = {"current": args.current, "mismatch": args.mismatch}
    return Settings(args.episodes, args.seed, args.workers, conditions, args.max_cycles)


def cases_of(args: argparse.Namespace) -> list[Case]:
    """The cases of ``add_case_arguments``' flags."""
    chosen = cases(tuple(args.n_agents), not args.no_paper, args.bars, not args.no_rings)
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
        help="no evaluation: the ladder of these runs' episodes.csv together (same seed)",
    )
    add_case_arguments(ap, TEAM_SIZES, "runs/ladder")
    args = ap.parse_args(argv)
    if args.sources:
        result = merged(args.sources, args.seed, args.out)
        print(markdown(result))
        print(f"wrote {args.out}/ladder.md, ladder.json and price_vs_n.png")
        return
    policies = args.policy or list(LADDER)
    # a rung that cannot be loaded, a case the environment refuses: before any episode
    with usage_errors(ap, (UsageError,)):
        result = run(policies, cases_of(args), settings_of(args), args.out)
    print(markdown(result))
    print(f"wrote {args.out}/ladder.md, ladder.json, price_vs_n.png and the evaluator's outputs")


if __name__ == "__main__":
    main()
