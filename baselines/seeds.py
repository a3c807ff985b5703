"""A learned policy over its training seeds: the interquartile mean and stratified bootstrap
intervals (Agarwal et al. 2021, through ``rliable``) of every seed's model on the same
evaluation's episodes.

    python -m baselines.ladder --policy dagger:runs/d0 --policy dagger:runs/d1 \\
        --policy dagger:runs/d2 --episodes 10 --seed 202 --out runs/ladder_seeds
    python -m baselines.seeds runs/ladder_seeds/episodes.csv \\
        --group "DAgger=dagger:runs/d0,dagger:runs/d1,dagger:runs/d2" --out runs/seeds

Several episodes.csv (runs of the same seed played apart) are read as one. A group's
score matrix is seeds x cases (the rows' ``scenario``); bootstrap intervals resample
seeds within each case. Each group's seeds are also ranked by the committed-seed rule
(``rank_by_rule``; run on ``dev``'s episodes, it names the seed a method commits).
Reference: docs/rl.md, docs/evaluation.md ("Learned methods: five seeds, one rule").

May import: the standard library, numpy, ``baselines.evaluation`` (the episodes.csv reader,
the Markdown table), ``baselines.command_line`` and ``baselines.stats``
(rliable's intervals).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from baselines.command_line import command_parser, existing_path, usage_errors
from baselines.evaluation.outputs import read_episodes
from baselines.evaluation.report import table
from baselines.stats import iqm_and_mean

METRICS = {
    "success": "success rate",
    "clean_success": "clean success rate",
    "clean_success_tol": "clean success rate within the 5 % band",
    "excess": "mean graded excess per period",
    "violation_periods": "median violation periods per episode",
    "return": "mean return per episode",
}
# the per-episode values a case's score averages (the rest are rates of flags, but
# violation periods: their median)
MEANS = ("return", "excess")


def parse_group(text: str) -> tuple[str, list[str]]:
    """``NAME=POLICY,POLICY,...`` -> (name, policies); an argparse ``type``."""
    name, sep, policies = text.partition("=")
    if not sep or not name or not policies:
        raise argparse.ArgumentTypeError(f"expected NAME=POLICY,POLICY,..., got {text!r}")
    return name, [p for p in policies.split(",") if p]


def score_matrix(
    rows: list[dict[str, Any]], policies: list[str], metric: str
) -> tuple[np.ndarray, list[str]]:
    """(seeds x cases) scores of ``metric`` and the cases, in the rows' order."""
    cases = list(dict.fromkeys(r["scenario"] for r in rows if r["policy"] in policies))
    scores = np.full((len(policies), len(cases)), np.nan)
    for i, policy in enumerate(policies):
        for j, case in enumerate(cases):
            mine = [r for r in rows if r["policy"] == policy and r["scenario"] == case]
            if not mine:
                continue
            if metric == "violation_periods":
                scores[i, j] = float(np.median([float(r[metric] or 0.0) for r in mine]))
            elif metric in MEANS:
                scores[i, j] = float(np.nanmean([float(r[metric]) for r in mine]))
            else:
                scores[i, j] = float(np.mean([bool(r[metric]) for r in mine]))
    missing = [policies[i] for i in range(len(policies)) if np.isnan(scores[i]).all()]
    if missing:
        raise ValueError(f"--group: no episodes of {missing} in the episodes.csv given")
    return scores, cases


def rank_by_rule(rows: list[dict[str, Any]], policies: list[str]) -> list[dict[str, Any]]:
    """The seeds' models best first by the committed-seed rule: the most clean successes
    summed over the cases, then the most successes, then the lower mean graded excess per
    period. Only seeds that played the same episodes compare; else a ``ValueError``."""
    played = {
        p: {(r["scenario"], str(r["episode"])) for r in rows if r["policy"] == p} for p in policies
    }
    if len({frozenset(v) for v in played.values()}) > 1:
        raise ValueError(
            f"the committed-seed rule compares seeds on the same episodes; {policies} "
            "played different ones"
        )
    keyed = []
    for policy in policies:
        mine = [r for r in rows if r["policy"] == policy]
        keyed.append({
            "policy": policy,
            "clean_success": sum(bool(r["clean_success"]) for r in mine),
            "success": sum(bool(r["success"]) for r in mine),
            # an episode the policy failed to play (an error) has no excess
            "excess": float(np.mean([r["excess"] for r in mine if r["excess"] is not None])),
            "episodes": len(mine),
        })  # fmt: skip
    return sorted(keyed, key=lambda k: (-k["clean_success"], -k["success"], k["excess"]))


def report(rows: list[dict[str, Any]], groups: dict[str, list[str]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, policies in groups.items():
        entry: dict[str, Any] = {"policies": policies, "metrics": {}}
        mine = [r for r in rows if r["policy"] in policies]
        for metric in (m for m in METRICS if any(m in r for r in mine)):  # older files: fewer
            scores, cases = score_matrix(rows, policies, metric)
            entry["cases"] = cases
            entry["metrics"][metric] = {
                **iqm_and_mean(scores),
                "per_seed": scores.tolist(),
            }
        if all("excess" in r for r in mine):  # older files carry no graded excess
            try:
                entry["rule"] = rank_by_rule(rows, policies)
            except ValueError as e:
                entry["rule_not_ranked"] = str(e)
        out[name] = entry
    return out


def markdown(summary: dict[str, Any]) -> str:
    lines = table("group | metric | IQM [95% CI] | mean [95% CI]")
    for name, entry in summary.items():
        for metric, title in METRICS.items():
            if metric not in entry["metrics"]:
                continue
            m = entry["metrics"][metric]
            iqm, mean = m["iqm"], m["mean"]
            lines.append(
                f"| {name} | {title} | {iqm[0]:.3g} [{iqm[1]:.3g}, {iqm[2]:.3g}] | "
                f"{mean[0]:.3g} [{mean[1]:.3g}, {mean[2]:.3g}] |"
            )
    for name, entry in summary.items():
        lines += ["", f"{name}, per seed (rows) and case (columns):", ""]
        lines += table(
            "metric | seed | " + " | ".join(entry["cases"]),
            (
                [title, i, *(f"{v:.3g}" for v in scores)]
                for metric, title in METRICS.items()
                if metric in entry["metrics"]
                for i, scores in enumerate(entry["metrics"][metric]["per_seed"])
            ),
        )
    for name, entry in summary.items():
        if "rule_not_ranked" in entry:
            lines += ["", f"{name}: not ranked ({entry['rule_not_ranked']})"]
        elif "rule" in entry:
            lines += ["", f"{name}, its seeds by the committed-seed rule (on `dev`):", ""]
            lines += table(
                "rank | policy | clean successes | successes | mean excess / period | episodes",
                ([i + 1, f"`{k['policy']}`", k["clean_success"], k["success"],
                  f"{k['excess']:.3f}", k["episodes"]] for i, k in enumerate(entry["rule"])),
            )  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.seeds", __doc__)
    ap.add_argument(
        "episodes", type=Path, nargs="+", help="evaluators' or ladders' episodes.csv (same seed)"
    )
    ap.add_argument(
        "--group", action="append", type=parse_group, required=True, metavar="NAME=POLICY,POLICY"
    )
    ap.add_argument("--out", type=Path, default=Path("runs/seeds"))
    args = ap.parse_args(argv)
    # checked after parsing, not as the positional's type: ``FILE --help`` shows the help
    with usage_errors(ap, (argparse.ArgumentTypeError,)):
        for path in args.episodes:
            existing_path(str(path))
    groups = dict(args.group)
    rows = [r for p in args.episodes for r in read_episodes(p)]
    with usage_errors(ap, (ValueError,)):  # a group's policy without episodes in the files
        for policies in groups.values():
            score_matrix(rows, policies, next(iter(METRICS)))
    summary = report(rows, groups)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "seeds.json").write_text(json.dumps(summary, indent=2) + "\n")
    text = markdown(summary)
    (args.out / "seeds.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
