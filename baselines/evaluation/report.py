"""The evaluator's report: the Markdown table of its summaries and its plots (success by
scenario, decision times, the paths on the paper scenario), and the figure helpers the
ladder and the channel sweep draw with.

May import: the standard library, numpy, matplotlib (inside functions: the Agg backend,
chosen before pyplot loads), ``baselines.evaluation.summary`` and ``uvms_env.scenarios``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from baselines.evaluation.summary import END_KINDS, VIOLATION_KINDS, failures

Row = dict[str, Any]


def failure_lines(rows: Sequence[Row]) -> list[str]:
    """A line per policy with failed episodes: how many of its episodes, and the first
    one's error (its first line) with where it happened."""
    return [
        f"{f['policy']}: {f['failed']} of {f['episodes']} episodes failed; first "
        f"({f['scenario']}, episode {f['episode']}): {str(f['error']).splitlines()[0]}"
        for f in failures(rows)
    ]


def table(head: str, rows: Iterable[Sequence[Any]] = ()) -> list[str]:
    """A Markdown table's lines: ``head`` (its cells joined by " | "), the rule under it,
    then a line per row of cells (each as ``str`` writes it). Every command's tables."""
    rule = "|" + "---|" * (head.count(" | ") + 1)
    return [f"| {head} |", rule, *("| " + " | ".join(map(str, r)) + " |" for r in rows)]


def markdown_table(summaries: Sequence[Row], failed: Sequence[str] = ()) -> str:
    """``results.md``: a row per summary (``aggregate``), then the violations per kind and
    how the episodes ended, what ``information`` means when a team policy is among them
    and the ``failed`` lines (``failure_lines``)."""

    def fmt(x: Any, digits: int = 2) -> str:
        return (
            "n/a"
            if x is None or (isinstance(x, float) and not np.isfinite(x))
            else f"{x:.{digits}f}"
        )

    def counts(s: Row, kinds: Sequence[str], of: dict[str, int] | None) -> list[Any]:
        return [s["policy"], s["scenario"], *(of[k] if of else "n/a" for k in kinds)]

    lines = table(
        "policy | information | scenario | episodes | current out of reach | "
        "success [95% CI] | clean success | final pos. error m | min clearance m | "
        "internal wrench rms | control effort | violations (total) | violations / episode | "
        "intervention rate | decision ms median / p95 | errors"
    )
    for s in summaries:
        lo, hi = s["success_ci95"]
        t = s["policy_time_ms"]
        lines.append(
            f"| {s['policy']} | {s.get('information', 'local')} | {s['scenario']} | "
            f"{s['episodes']} | "
            f"{s.get('out_of_reach', 0)} | {fmt(s['success_rate'])} [{fmt(lo)}, {fmt(hi)}] | "
            f"{fmt(s.get('clean_success_rate'))} | "
            f"{fmt(s.get('final_pos_error_m'))} | {fmt(s.get('min_obstacle_clearance_m'))} | "
            f"{fmt(s.get('internal_wrench_rms'))} | {fmt(s.get('control_effort'))} | "
            f"{sum(s['violations'].values())} | "
            f"{fmt(sum(s['violations'].values()) / s['episodes'], 1)} | "
            f"{fmt(s.get('intervention_rate'), 3)} | "
            f"{fmt(t['median'], 3)} / {fmt(t['p95'], 3)} | {s['errors']} |"
        )
    for kinds, key in ((VIOLATION_KINDS, "violations"), (END_KINDS, "episode_ends")):
        rows = (counts(s, kinds, s.get(key)) for s in summaries)
        lines += ["", *table(f"policy | scenario | {' | '.join(kinds)}", rows)]
    if any(s.get("information") == "full" for s in summaries):
        lines += [
            "",
            "information `full`: a team policy that sees the global state and decides for "
            "every robot (the full-information reference, not a decentralized entry); `local`: "
            "one policy per robot on its own observation. Decision time: per team decision "
            "for `full`, per agent decision for `local`.",
        ]
    if failed:
        lines += ["", "Failed episodes (the rows' `error` in episodes.csv):", ""]
        lines += [f"* {line}" for line in failed]
    return "\n".join(lines) + "\n"


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: Path, dpi: int = 120, rect: tuple[float, ...] | None = None) -> None:
    """Lay the figure out (within ``rect`` of it: room for a figure legend), write it (its
    folder made where missing) and free it."""
    fig.tight_layout(rect=rect)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)


def write_plots(rows: Sequence[Row], summaries: Sequence[Row], out: Path) -> None:
    """``success_by_scenario.png``, ``decision_time.png`` and, with the object's path on the
    paper scenario's first episode, ``paths_paper.png`` in ``out``."""
    policies = list(dict.fromkeys(s["policy"] for s in summaries))
    success_plot(summaries, policies, out / "success_by_scenario.png")
    decision_time_plot(rows, policies, out / "decision_time.png")
    paths = [r for r in rows if r["scenario"] == "paper" and r["episode"] == 0 and r["_path"]]
    if paths:
        paths_plot(paths, policies, out / "paths_paper.png")


def success_plot(summaries: Sequence[Row], policies: list[str], path: Path) -> None:
    """A bar per policy and scenario: the success rate with its Wilson interval, and
    inside it (hatched) the clean success rate, the part with no violation period."""
    plt = pyplot()
    scenarios = sorted({s["scenario"] for s in summaries})
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(scenarios) + 2.0), 3.8))
    width = 0.8 / max(1, len(policies))
    by = {(s["policy"], s["scenario"]): s for s in summaries}
    for k, policy in enumerate(policies):
        for j, scen in enumerate(scenarios):
            s = by.get((policy, scen))
            if s is None:
                continue
            lo, hi = s["success_ci95"]
            rate, x = s["success_rate"], j + k * width
            ax.bar(x, rate, width, color=f"C{k}", alpha=0.45, label=policy if j == 0 else None)
            clean = s.get("clean_success_rate")
            if clean is not None:
                ax.bar(x, clean, width, color=f"C{k}", hatch="//", edgecolor="k", linewidth=0)
            yerr = [[max(0.0, rate - lo)], [max(0.0, hi - rate)]]  # rounding: never < 0
            ax.errorbar(x, rate, yerr=yerr, color="k", capsize=3)
    ticks = np.arange(len(scenarios)) + width * (len(policies) - 1) / 2
    long = len(scenarios) > 4 or max((len(s) for s in scenarios), default=0) > 12
    ax.set_xticks(ticks, scenarios, rotation=30 if long else 0, ha="right" if long else "center")
    ax.set_ylabel("success rate (Wilson 95%);\nhatched: clean success")
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=8)
    save(fig, path)


def decision_time_plot(rows: Sequence[Row], policies: list[str], path: Path) -> None:
    """A box per policy of its decision times; a policy without a positive time (every
    episode failed before deciding) is left out, and a figure with none says so."""
    fig, ax = pyplot().subplots(figsize=(6, 3.5))
    data = {}
    for p in policies:
        ms = np.concatenate(
            [np.asarray(r.get("_decision_ms", []), float) for r in rows if r["policy"] == p]
            or [np.zeros(0)]
        )
        ms = ms[np.isfinite(ms) & (ms > 0)]  # the log scale takes positive values only
        if len(ms):
            data[p] = ms
    if data:
        ax.boxplot(list(data.values()), showfliers=False)
        ax.set_xticks(np.arange(1, len(data) + 1), list(data))
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no decision times: no episode decided", ha="center", va="center")
        ax.set_xticks([])
    ax.set_ylabel("decision time per agent [ms]")
    save(fig, path)


def paths_plot(paths: Sequence[Row], policies: list[str], path: Path) -> None:
    """The object's path of each row on the paper scenario, its obstacles (with the team's
    clearance radius dotted) and waypoints."""
    from uvms_env.scenarios import make

    plt = pyplot()
    scen = make("paper")
    fig, ax = plt.subplots(figsize=(6, 5))
    for obs in scen.obstacles:
        ax.add_patch(plt.Circle((obs.y, obs.x), obs.radius, color="0.5"))
        ax.add_patch(plt.Circle((obs.y, obs.x), obs.radius + scen.team_radius, fill=False, ls=":"))
    for r in paths:
        p = np.array(r["_path"])
        ax.plot(p[:, 1], p[:, 0], color=f"C{policies.index(r['policy'])}", label=r["policy"])
    ax.plot(scen.waypoints[:, 1], scen.waypoints[:, 0], "k*", ms=12, label="waypoints")
    ax.set_xlabel("y (east) [m]")
    ax.set_ylabel("x (north) [m]")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    save(fig, path)
