"""The communication sweep: the talking expert over a grid of acoustic channels.

    python -m baselines.comm_sweep --episodes 10 --seed 202 --workers 2 --out runs/comm_sweep

The talking expert (``nmpc:comm``) plays the ladder's cases under every point of a grid of
channels (bit rate x loss probability x modem latency, variations of ``--preset``) and
under ``ideal``; the silent expert and the full-information reference play the same episodes once,
without a channel (neither talks, and the channel changes no physics draw).
Reference: docs/channel.md.

May import: the standard library, numpy, ``uvms_env.robot.channel``, ``baselines.evaluation``,
``baselines.command_line`` and ``baselines.ladder``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baselines.command_line import command_parser, usage_errors
from baselines.evaluation.outputs import Play, run_and_write, write_result
from baselines.evaluation.report import pyplot, save, table
from baselines.evaluation.runner import Case, Settings, UsageError
from baselines.evaluation.summary import groups
from baselines.ladder import (
    CENTRAL,
    EXPERT,
    PRICED,
    TALKER,
    add_case_arguments,
    case_order,
    cases_of,
    fmt,
    price,
    rung_summary,
    settings_of,
)
from uvms_env.robot.channel import ChannelSettings, channel_settings

IDEAL = "ideal"
PRESET = "atm900"
# the default grid: a micro-modem's rate and the atm900's; no loss and the loss of a bad
# acoustic day; the atm900's modem latency. Small enough for 2 cores (module docstring)
BIT_RATES = (80.0, 2400.0)
LOSSES = (0.0, 0.5)
LATENCIES = (4,)
SWEEP_TEAM_SIZES = (2, 4, 6)  # the ladder's TEAM_SIZES thinned: each case is one more run
SEPARATOR = " | "  # between the case and the channel in a channel point's case label
CURVE = {
    "completion periods": "completion_periods_imputed",
    "internal wrench rms": "internal_wrench_rms",
}


@dataclass(frozen=True)
class ChannelPoint:
    """One channel of the sweep: a label and its settings."""

    label: str
    settings: ChannelSettings
    bit_rate: float
    loss: float
    latency: int


def grid(
    preset: str = PRESET,
    bit_rates: tuple[float, ...] = BIT_RATES,
    losses: tuple[float, ...] = LOSSES,
    latencies: tuple[int, ...] = LATENCIES,
) -> list[ChannelPoint]:
    """The ``ideal`` channel, then every (bit rate, loss, latency) as a variation of
    ``preset``'s settings (ValueError, naming the field, on an impossible one)."""
    base = channel_settings(preset)
    ideal = channel_settings(IDEAL)
    if base is None or ideal is None:
        raise ValueError(f"the sweep needs a channel preset, got {preset!r}")
    points = [ChannelPoint(IDEAL, ideal, ideal.bit_rate_bps, 0.0, 0)]
    for rate, loss, latency in itertools.product(bit_rates, losses, latencies):
        s = dataclasses.replace(
            base,
            bit_rate_bps=float(rate),
            loss_probability=float(loss),
            modem_latency_periods=int(latency),
        )
        label = f"{rate:g} bit/s, loss {loss:g}, latency {latency}"
        points.append(ChannelPoint(label, s, float(rate), float(loss), int(latency)))
    return points


def sweep_cases(base: list[Case], points: list[ChannelPoint]) -> list[Case]:
    """Each case under each channel: the case's keywords with ``comm``, labelled
    "case | channel" (episode seeds come from the scenario: the same episodes)."""
    return [
        Case(f"{c.label}{SEPARATOR}{p.label}", c.scenario, (*c.overrides, ("comm", p.settings)))
        for c in base
        for p in points
    ]


def summarize(
    rows: list[dict[str, Any]], labels: list[str], points: list[ChannelPoint], seed: int
) -> dict[str, Any]:
    """Per (case, policy or channel): the rates and means (``baselines.ladder``'s rung
    summary) and, for the talking expert and the reference, the ratios of means against the
    silent expert on the paired episodes; pooled over the cases, the clean success and
    the mean of the per-case ratios (each case counts once, whatever its scale)."""
    # the case in ``scenario`` and the channel in the policy's name (``nmpc:comm [channel]``),
    # so that a talking run pairs with the references
    split = []
    for r in rows:
        case, _, channel = r["scenario"].partition(SEPARATOR)
        policy = f"{r['policy']} [{channel}]" if channel else r["policy"]
        split.append({**r, "scenario": case, "policy": policy, "channel": channel or "none"})
    by = groups(split)
    # the runs in the tables' order, each with its channel point (None: no channel)
    runs = {EXPERT: None, CENTRAL: None, **{f"{TALKER} [{p.label}]": p for p in points}}
    everything, pooled = [], []
    for run, point in runs.items():
        per_case = []
        for case in labels:
            group = by.get((run, case))
            if not group:
                continue
            s = rung_summary(group, seed)
            if run != EXPERT:
                p = price(split, run, EXPERT, case, seed)
                for name, key in PRICED.items():
                    s[f"{key}_ratio"] = p[name]["ratio"] if p[name] else None
                s["paired"] = p["episodes"]
            s["run"], s["channel"] = run, group[0]["channel"]
            per_case.append(s)
        if not per_case:
            continue
        everything += per_case
        n = sum(s["episodes"] - s["out_of_reach"] for s in per_case)
        entry: dict[str, Any] = {
            "run": run,
            "channel": per_case[0]["channel"],
            "cases": len(per_case),
            "clean_success_rate": sum(s["clean_success"] for s in per_case) / n if n else None,
        }
        for key in PRICED.values():
            ok = [x for s in per_case if (x := s.get(f"{key}_ratio")) is not None]
            entry[f"{key}_ratio"] = 1.0 if run == EXPERT else (float(np.mean(ok)) if ok else None)
        if point is not None:
            entry.update(bit_rate=point.bit_rate, loss=point.loss, latency=point.latency)
        pooled.append(entry)
    return {"per_case": everything, "pooled": pooled}


def markdown(result: dict[str, Any]) -> str:
    lines = [
        "Pooled over the cases (ratios: the mean over the cases of each case's ratio of means "
        "against the silent expert over the paired episodes, a failure's completion counted "
        "at the cap; < 1: better):",
        "",
        *table(
            "run | clean success | " + " | ".join(f"{name} ratio" for name in PRICED),
            (
                [f"`{e['run']}`", fmt(e["clean_success_rate"])]
                + [fmt(e[f"{key}_ratio"], 3) for key in PRICED.values()]
                for e in result["pooled"]
            ),
        ),
        "",
        *table(
            "case | run | clean success | completion periods | internal wrench rms N | "
            "ratios vs silent: completion / wrench (paired)"
        ),
    ]
    for s in sorted(result["per_case"], key=case_order):
        n = s["episodes"] - s["out_of_reach"]
        ratios = (
            f"{fmt(s.get('completion_periods_imputed_ratio'), 3)} / "
            f"{fmt(s.get('internal_wrench_rms_ratio'), 3)} ({s['paired']})"
            if "paired" in s
            else "1 / 1"
        )
        lines.append(
            f"| {s['scenario']} | `{s['run']}` | {s['clean_success']}/{n} | "
            f"{fmt(s.get('completion_periods'), 0)} | {fmt(s.get('internal_wrench_rms'), 2)} | "
            f"{ratios} |"
        )
    return "\n".join(lines) + "\n"


def write_csv(result: dict[str, Any], path: Path) -> None:
    """``sweep.csv``: a row per (case, run) of ``per_case``, its counts, means and ratios
    (empty where a run has none: the silent expert's ratios)."""
    ratios = [f"{key}_ratio" for key in PRICED.values()]
    keys = ["scenario", "run", "channel", "episodes", "clean_success", "success"]
    keys += [*PRICED.values(), *ratios, "paired"]
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, restval="", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(result["per_case"])


def plot_curve(result: dict[str, Any], out: Path) -> None:
    """``comm_curve.png``: per panel (clean success, the completion time and internal
    wrench ratios against the silent expert) the talking expert against the bit rate,
    one line per (loss, latency); the silent expert, the ``ideal`` channel and the
    full-information reference as horizontal lines. An unlimited rate sits right of the others."""
    pooled = result["pooled"]
    ref = {e["run"]: e for e in pooled}
    talk = [e for e in pooled if "bit_rate" in e and e["channel"] != IDEAL]
    finite = [e["bit_rate"] for e in talk if math.isfinite(e["bit_rate"])] or [1.0]
    far = max(finite) * 10.0  # where an unlimited rate is drawn

    def x(rate: float) -> float:
        return rate if math.isfinite(rate) else far

    panels = [("clean success", "clean_success_rate")] + [
        (f"{name} / silent expert", f"{key}_ratio") for name, key in CURVE.items()
    ]
    fig, axes = pyplot().subplots(1, len(panels), figsize=(4.4 * len(panels), 3.6))
    for ax, (title, key) in zip(axes, panels, strict=True):
        lines: dict[tuple[float, int], list[tuple[float, float]]] = {}
        for e in talk:
            if e.get(key) is not None:
                lines.setdefault((e["loss"], e["latency"]), []).append((x(e["bit_rate"]), e[key]))
        for (loss, latency), pts in sorted(lines.items()):
            pts.sort()
            ax.plot(*zip(*pts, strict=True), "-o", label=f"loss {loss:g}, latency {latency}")
        for run, label, style in (
            (EXPERT, "silent expert", "k-"),
            (f"{TALKER} [{IDEAL}]", "talking, ideal channel", "g--"),
            (CENTRAL, "full-information reference", "r:"),
        ):
            if run in ref and ref[run].get(key) is not None:
                ax.axhline(ref[run][key], color=style[0], ls=style[1:], lw=1.2, label=label)
        ax.set_xscale("log")
        ax.set_xlabel("bit rate, bit/s")
        ax.set_title(title)
        if any(not math.isfinite(e["bit_rate"]) for e in talk):
            ax.set_xticks(
                [*sorted(set(finite)), far], [*(f"{r:g}" for r in sorted(set(finite))), "inf"]
            )
    axes[0].legend(fontsize=7)
    save(fig, out / "comm_curve.png")


def run(
    points: list[ChannelPoint],
    base: list[Case],
    settings: Settings,
    out: Path,
    references: bool = True,
) -> dict[str, Any]:
    """Evaluate the talking expert on every (case, channel), the references once per case
    (without a channel), write every output, return the sweep's summaries."""
    plays: list[Play] = [([TALKER], sweep_cases(base, points))]
    if references:
        plays.append(([EXPERT, CENTRAL], base))
    rows, _ = run_and_write(settings, plays, out)
    result = summarize(rows, [c.label for c in base], points, settings.seed)
    channels = {p.label: dataclasses.asdict(p.settings) for p in points}
    write_result(
        out, "sweep", result, markdown(result), {**settings.record(), "channels": channels}
    )
    write_csv(result, out / "sweep.csv")
    plot_curve(result, out)
    return result


def numbers(kind: type) -> Any:
    """An argparse ``type``: comma-separated numbers of ``kind`` (int: whole numbers)."""

    def parse(text: str) -> tuple[Any, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected comma-separated numbers, got {text!r}"
            ) from None
        if kind is int and not all(v.is_integer() for v in values):
            raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers: {text!r}")
        return tuple(kind(v) for v in values)

    return parse


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.comm_sweep", __doc__)
    ap.add_argument("--preset", default=PRESET, help="the channel the grid varies")
    for flag, kind, values, what in (
        ("--bit-rates", float, BIT_RATES, "comma-separated, bit/s (inf: unlimited)"),
        ("--losses", float, LOSSES, "loss floors p0"),
        ("--latencies", int, LATENCIES, "modem latency, periods"),
    ):
        ap.add_argument(
            flag, type=numbers(kind), default=",".join(f"{v:g}" for v in values), help=what
        )
    ap.add_argument("--no-references", action="store_true", help="no silent / central runs")
    add_case_arguments(ap, SWEEP_TEAM_SIZES, "runs/comm_sweep", bars=False)
    args = ap.parse_args(argv)
    with usage_errors(ap, (ValueError,)):  # the grid: an impossible channel, named
        points = grid(args.preset, args.bit_rates, args.losses, args.latencies)
    # a case the environment refuses: before any episode
    with usage_errors(ap, (UsageError,)):
        result = run(
            points, cases_of(args), settings_of(args), args.out, references=not args.no_references
        )
    print(markdown(result))
    print(
        f"wrote {args.out}/sweep.md, sweep.csv, sweep.json, comm_curve.png and the "
        "evaluator's outputs"
    )


if __name__ == "__main__":
    main()
