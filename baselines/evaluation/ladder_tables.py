"""The ladder's result from the evaluator's rows, and its tables and figures.

* ``ladder``: per rung and case its summary (``rung_summary``), per group of cases (rings,
  bars, ``paper``) the pooled summary, and the paired comparisons (``paired.compare_all``,
  Holm within each table): of decentralization (each distributed expert against the
  full-information reference), of the expert's variants (each other distributed expert,
  an ablation's rows, against ``nmpc``), of learning (each other rung against the
  expert), of learning against the reference and of learning against the prior (each
  learned rung against its own starting point, the zero residual).
* ``main_table``: one row per rung: what it was trained on, then per group clean success
  and success (Wilson intervals), and over every case the graded excess and the return
  (bootstrap intervals) and the paired clean-success test against the expert.
* ``markdown``: the main table, the per-case table and the comparisons; ``plot_metrics``:
  one figure per metric against the team size; ``compute_table``: CPU-hours per rung.

May import: the standard library, numpy, ``baselines.stats`` and ``baselines.evaluation``
(summary, paired, report).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from baselines.evaluation.paired import PAIRED_METRICS, compare_all, paired_episodes
from baselines.evaluation.report import pyplot, save, table
from baselines.evaluation.summary import RATES, Row, groups, metric_values, summarize
from baselines.stats import holm, mcnemar_exact

CENTRAL = "nmpc:central"
EXPERT = "nmpc"
# the trivial rungs; ``prior`` (a_ss and the joint hold, a zero residual) is where every
# learned residual policy starts, so each learned rung is also compared against it
PRIOR = "prior"
TRIVIAL = (PRIOR, "zero", "random")
#: The groups of cases the main table pools: name -> the prefix of its cases' labels.
CASE_GROUPS = {"rings": "random N=", "bars": "random bar N=", "paper": "paper"}
#: The metrics of the figures against N: name -> (the summary's key, a rate or a mean).
FIGURE_METRICS = {
    "clean success": ("clean_success_rate", True),
    "success": ("success_rate", True),
    "graded excess per period": ("excess", False),
    "return": ("return", False),
}


def case_group(label: str) -> str | None:
    return next((g for g, prefix in CASE_GROUPS.items() if label.startswith(prefix)), None)


def rung_summary(rows: Sequence[Row], seed: int) -> Row:
    """One rung on one case (or a pooled group): ``summarize`` over the episodes within
    reach with the paired metrics' means, completion time over the successes, the
    violation periods, and the decision time's median and p95."""
    means = ("completion_periods", *PAIRED_METRICS.values(), "violated_fraction")
    out = summarize(rows, seed, (*means, "max_excess", "violation_periods"), within_reach_only=True)
    for key in ("violations", "intervention_rate", "intervention_mean"):
        del out[key]
    times = out.pop("policy_time_ms")
    out["decision_ms_median"], out["decision_ms_p95"] = times["median"], times["p95"]
    out["wall_s"] = float(np.nansum(metric_values(rows, "wall_s")))
    return out


def ladder(rows: Sequence[Row], policies: Sequence[str], labels: Sequence[str], seed: int) -> Row:
    """The ladder's summaries, pooled groups and paired comparisons from the rows."""
    by = groups(rows)
    rungs = [rung_summary(by[p, c], seed) for p in policies for c in labels if (p, c) in by]
    pooled = []
    for p in policies:
        for name in CASE_GROUPS:
            mine = [r for c in labels if case_group(c) == name for r in by.get((p, c), [])]
            if mine:
                pooled.append({**rung_summary(mine, seed), "scenario": name})
        everything = [r for c in labels for r in by.get((p, c), [])]
        if everything:
            pooled.append({**rung_summary(everything, seed), "scenario": "all"})
    distributed = [p for p in policies if p.startswith("nmpc") and p != CENTRAL]
    others = [p for p in policies if not p.startswith("nmpc")]
    learned = [p for p in others if p not in TRIVIAL]
    kinds = {
        "decentralization": [(p, CENTRAL) for p in distributed],
        "the expert's variants": [(p, EXPERT) for p in distributed if p != EXPERT],
        "learning": [(p, EXPERT) for p in others],
        "learning against the reference": [(p, CENTRAL) for p in others],
        "learning against the prior": [(p, PRIOR) for p in learned],
    }
    comparisons = {
        kind: compare_all(rows, pairs, labels, seed)
        if {r for _, r in pairs} <= set(policies)
        else []
        for kind, pairs in kinds.items()
    }
    against = pooled_against(rows, [p for p in policies if p != EXPERT], EXPERT, labels)
    return {"rungs": rungs, "pooled": pooled, "prices": comparisons, "against_expert": against}


def pooled_against(
    rows: Sequence[Row], rungs: Sequence[str], reference: str, labels: Sequence[str]
) -> list[Row]:
    """Each rung against ``reference`` over every case's paired episodes together: the
    exact McNemar test of success and of clean success, Holm-corrected over the rungs."""
    out = []
    for rung in rungs:
        a, b = [], []
        for case in labels:
            x, y = paired_episodes(rows, rung, reference, case)
            a += x
            b += y
        if not a:
            continue
        entry: Row = {"rung": rung, "reference": reference, "episodes": len(a)}
        for name in RATES:
            test = mcnemar_exact([bool(r.get(name)) for r in a], [bool(r.get(name)) for r in b])
            diff = (sum(bool(r.get(name)) for r in a) - sum(bool(r.get(name)) for r in b)) / len(a)
            entry[name] = {"difference": diff, **test}
        out.append(entry)
    for name in RATES:
        tests = [e[name] for e in out]
        for test, adjusted in zip(tests, holm([t["p"] for t in tests]), strict=True):
            test["p_holm"] = adjusted
    return out


# -- tables -----------------------------------------------------------------------------------
def fmt(x: Any, digits: int = 2) -> str:
    """A table cell: n/a for None or a non-finite number."""
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "n/a"
    return f"{x:,.{digits}f}" if isinstance(x, float) else str(x)


def interval(x: Any, bounds: Any, digits: int = 2) -> str:
    """A table cell: ``x [low, high]``; n/a without ``x``."""
    if x is None:
        return "n/a"
    if bounds is None:
        return fmt(x, digits)
    return f"{fmt(x, digits)} [{fmt(bounds[0], digits)}, {fmt(bounds[1], digits)}]"


def rate(s: Row | None, name: str) -> str:
    """``k/n [low, high]`` of a summary's rate (percent-free: counts with the interval)."""
    if s is None:
        return ""
    n = s["episodes"] - s["out_of_reach"]
    if not n:
        return "n/a"
    lo, hi = s[f"{name}_ci95"]
    return f"{s[name]}/{n} [{fmt(lo)}, {fmt(hi)}]"


def case_order(summary: Row) -> tuple[bool, str]:
    """Tables list the cases random N = 2..6 first, then paper."""
    return (summary["scenario"] == "paper", summary["scenario"])


def main_table(result: Row, trained: dict[str, str]) -> list[str]:
    """The compact main table (module docstring); ``trained``: rung -> what it was trained
    on (its model card), "" for the controllers and the trivial rungs."""
    pooled = {(s["policy"], s["scenario"]): s for s in result["pooled"]}
    against = {e["rung"]: e for e in result["against_expert"]}
    policies = list(dict.fromkeys(s["policy"] for s in result["pooled"]))
    present = [g for g in CASE_GROUPS if any((p, g) in pooled for p in policies)]
    head = "rung | information | trained on (paper / bars, budget, seeds) | "
    head += " | ".join(f"{g}: clean success | {g}: success" for g in present)
    head += " | excess / period | return | clean success vs `nmpc` (Holm p)"
    lines = table(head)
    for p in policies:
        everything = pooled.get((p, "all"))
        cells = [f"`{p}`", everything["information"] if everything else "", trained.get(p, "")]
        for g in present:
            s = pooled.get((p, g))
            cells += [rate(s, "clean_success"), rate(s, "success")]
        cells.append(interval(everything.get("excess"), everything.get("excess_ci95"), 3))
        cells.append(interval(everything.get("return"), everything.get("return_ci95"), 0))
        e = against.get(p)
        cells.append(
            f"{e['clean_success']['difference']:+.2f} (p {fmt(e['clean_success']['p_holm'], 3)})"
            if e
            else ""
        )
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def case_table(result: Row) -> list[str]:
    """Per rung and case: the rates, the graded safety, the return, the paired metrics'
    means and the decision time."""
    lines = table(
        "scenario | policy | information | success | clean success | clean within 5 % | "
        "excess / period | largest excess | violated robot-periods | return | "
        "completion periods (successes) | internal wrench rms N | effort / s | "
        "decision ms median / p95"
    )
    for s in sorted(result["rungs"], key=case_order):
        lines.append(
            f"| {s['scenario']} | `{s['policy']}` | {s['information']} | "
            f"{rate(s, 'success')} | {rate(s, 'clean_success')} | "
            f"{rate(s, 'clean_success_tol')} | "
            f"{interval(s.get('excess'), s.get('excess_ci95'), 3)} | "
            f"{fmt(s.get('max_excess'), 2)} | {fmt(s.get('violated_fraction'), 3)} | "
            f"{interval(s.get('return'), s.get('return_ci95'), 0)} | "
            f"{interval(s.get('completion_periods'), s.get('completion_periods_ci95'), 0)} | "
            f"{fmt(s.get('internal_wrench_rms'), 2)} | {fmt(s.get('effort_rate'), 3)} | "
            f"{fmt(s['decision_ms_median'], 3)} / {fmt(s['decision_ms_p95'], 3)} |"
        )
    return lines


def price_table(kind: str, comparisons: Sequence[Row]) -> list[str]:
    """One kind of paired comparison: per case and rung the episodes, the rates'
    differences with their Holm-corrected McNemar p, and per metric the mean difference
    [95 % CI], the ratio of means and the Holm-corrected Wilcoxon p."""
    lines = [
        "",
        f"Price of {kind} (rung minus reference over every paired episode, failures "
        "included: a failure's completion counted at the cap; rates: difference (Holm p of "
        "the exact McNemar test); metrics: mean difference [95% CI], ratio of means, Holm p "
        "of the Wilcoxon signed-rank test):",
        "",
        *table(
            "scenario | rung | reference | episodes | success | clean success | "
            + " | ".join(PAIRED_METRICS)
        ),
    ]
    for c in comparisons:
        rates = [
            f"{c[n]['difference']:+.2f} (p {fmt(c[n]['p_holm'], 3)})"
            if c[n]["difference"] is not None
            else "n/a"
            for n in ("success", "clean_success")
        ]
        metrics = [
            "n/a"
            if (v := c[name]) is None
            else f"{interval(v['difference'], v['difference_ci95'], 3)}"
            + (f", x{fmt(v['ratio'])}" if v["ratio"] is not None else "")
            + f", p {fmt(v['p_holm'], 3)}"
            for name in PAIRED_METRICS
        ]
        lines.append(
            f"| {c['scenario']} | `{c['rung']}` | `{c['reference']}` | {c['episodes']} | "
            + " | ".join(rates + metrics)
            + " |"
        )
    return lines


def compute_table(result: Row) -> list[str]:
    """CPU-hours per rung (the episodes' own wall time, one core each)."""
    pooled = [s for s in result["pooled"] if s["scenario"] == "all"]
    lines = table("rung | episodes | CPU-hours")
    total = 0.0
    for s in pooled:
        total += s["wall_s"]
        lines.append(f"| `{s['policy']}` | {s['episodes']} | {s['wall_s'] / 3600:.2f} |")
    lines.append(f"| all | {sum(s['episodes'] for s in pooled)} | {total / 3600:.2f} |")
    return lines


def markdown(result: Row, trained: dict[str, str]) -> str:
    lines = [
        "Main table (cases pooled per group; intervals 95 %):",
        "",
        *main_table(result, trained),
    ]
    lines += ["", "Per case:", "", *case_table(result)]
    for kind, comparisons in result["prices"].items():
        if comparisons:
            lines += price_table(kind, comparisons)
    lines += ["", "Compute:", "", *compute_table(result)]
    return "\n".join(lines) + "\n"


# -- figures ----------------------------------------------------------------------------------
def plot_metrics(result: Row, out: Path) -> list[Path]:
    """One figure per ``FIGURE_METRICS`` metric against N: rings and bars side by side, a
    line per rung (rates with their Wilson intervals as bars), ``paper`` as a marker at its
    N = 2. Returns the files written."""
    by = {(s["policy"], s["scenario"]): s for s in result["rungs"]}
    policies = list(dict.fromkeys(s["policy"] for s in result["rungs"]))
    written = []
    for title, (key, is_rate) in FIGURE_METRICS.items():
        fig, axes = pyplot().subplots(1, 2, figsize=(10.5, 4.6), sharey=True)
        for ax, group in zip(axes, ("rings", "bars"), strict=True):
            prefix = CASE_GROUPS[group]
            for k, p in enumerate(policies):
                pts = sorted(
                    (int(c.split("=")[1]), s)
                    for (q, c), s in by.items()
                    if q == p and c.startswith(prefix) and s.get(key) is not None
                )
                if not pts:
                    continue
                x = np.array([n for n, _ in pts], float) + 0.04 * (k - len(policies) / 2)
                y = np.array([s[key] for _, s in pts], float)
                style = dict(marker="o", lw=1.0, ms=3.5, label=p, color=f"C{k % 10}")
                if is_rate:
                    ci = np.array([s[f"{key.removesuffix('_rate')}_ci95"] for _, s in pts])
                    ax.errorbar(x, y, yerr=[y - ci[:, 0], ci[:, 1] - y], capsize=2, **style)
                else:
                    ax.plot(x, y, **style)
                if group == "rings" and (p, "paper") in by and by[p, "paper"].get(key) is not None:
                    ax.plot([2.0], [by[p, "paper"][key]], marker="*", ms=8, color=f"C{k % 10}")
            ax.set_title(f"{group}" + (" (star: paper)" if group == "rings" else ""))
            ax.set_xlabel("robots N")
            sizes = {int(c.split("=")[1]) for _, c in by if c.startswith(prefix)}
            ax.set_xticks(sorted(sizes) or range(2, 7))
        axes[0].set_ylabel(title)
        if key == "excess":  # from 0 to tens: a linear axis hides everything but the worst
            axes[0].set_yscale("symlog", linthresh=0.01)
            axes[0].set_ylim(bottom=0.0)
        handles, labels = axes[0].get_legend_handles_labels()
        rows = -(-len(labels) // 4)
        if handles:
            fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=4, frameon=False)
        path = out / f"ladder_{key.removesuffix('_rate')}_vs_n.png"
        save(fig, path, rect=(0, 0.05 * rows, 1, 1))
        written.append(path)
    return written
