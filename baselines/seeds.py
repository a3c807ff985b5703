"""A learned policy over its training seeds: the interquartile mean and stratified bootstrap
intervals (Agarwal et al. 2021, through ``rliable``) of every seed's model on the same
evaluation's episodes.

    python -m baselines.ladder --policy dagger:runs/d0 --policy dagger:runs/d1 \\
        --policy dagger:runs/d2 --episodes 10 --seed 202 --out runs/ladder_seeds
    python -m baselines.seeds runs/ladder_seeds/episodes.csv \\
        --group "DAgger=dagger:runs/d0,dagger:runs/d1,dagger:runs/d2" --out runs/seeds

Several episodes.csv (runs of the same seed played apart) are read as one. A group's
score matrix is seeds x cases (the rows' ``scenario``); bootstrap intervals resample
seeds within each case. Reference: docs/rl.md, docs/results.md.

May import: the standard library, numpy, rliable, ``baselines.evaluation.outputs`` (the
episodes.csv reader) and ``baselines.options``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from baselines.evaluation.outputs import read_episodes
from baselines.options import command_parser

METRICS = {
    "success": "success rate",
    "clean_success": "clean success rate",
    "violation_periods": "median violation periods per episode",
}
BOOTSTRAP_REPS = 2000


def parse_group(text: str) -> tuple[str, list[str]]:
    """``NAME=POLICY,POLICY,...`` -> (name, policies)."""
    name, sep, policies = text.partition("=")
    if not sep or not name or not policies:
        raise SystemExit(f"--group takes NAME=POLICY,POLICY,..., got {text!r}")
    return name, [p for p in policies.split(",") if p]


def score_matrix(
    rows: list[dict[str, Any]], policies: list[str], metric: str
) -> tuple[np.ndarray, list[str]]:
    """(seeds x cases) scores of ``metric`` and the cases, in the rows' order."""
    cases = list(dict.fromkeys(r["scenario"] for r in rows if r["policy"] in policies))
    table = np.full((len(policies), len(cases)), np.nan)
    for i, policy in enumerate(policies):
        for j, case in enumerate(cases):
            mine = [r for r in rows if r["policy"] == policy and r["scenario"] == case]
            if not mine:
                continue
            if metric == "violation_periods":
                table[i, j] = float(np.median([float(r[metric] or 0.0) for r in mine]))
            else:
                table[i, j] = float(np.mean([bool(r[metric]) for r in mine]))
    missing = [policies[i] for i in range(len(policies)) if np.isnan(table[i]).all()]
    if missing:
        raise ValueError(f"no episodes of {missing} in the rows")
    return table, cases


def interval_estimates(table: np.ndarray, seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """IQM and mean of a (seeds x cases) table, each (point, low, high) with a 95%
    stratified bootstrap interval (rliable)."""
    from rliable import library as rly
    from rliable import metrics

    def both(scores: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(scores), metrics.aggregate_mean(scores)])

    # rliable's stratified resampling draws from numpy's global generator whatever
    # random_state says (two calls gave two intervals): seed it, then put it back
    saved = np.random.get_state()  # noqa: NPY002 (the library's global state)
    np.random.seed(seed)  # noqa: NPY002
    try:
        point, interval = rly.get_interval_estimates(
            {"group": table}, both, reps=BOOTSTRAP_REPS, random_state=np.random.RandomState(seed)
        )
    finally:
        np.random.set_state(saved)  # noqa: NPY002
    p, ci = point["group"], interval["group"]
    return {
        "iqm": (float(p[0]), float(ci[0, 0]), float(ci[1, 0])),
        "mean": (float(p[1]), float(ci[0, 1]), float(ci[1, 1])),
    }


def report(rows: list[dict[str, Any]], groups: dict[str, list[str]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, policies in groups.items():
        entry: dict[str, Any] = {"policies": policies, "metrics": {}}
        for metric in METRICS:
            table, cases = score_matrix(rows, policies, metric)
            entry["cases"] = cases
            entry["metrics"][metric] = {
                **interval_estimates(table),
                "per_seed": table.tolist(),
            }
        out[name] = entry
    return out


def markdown(summary: dict[str, Any]) -> str:
    lines = [
        "| group | metric | IQM [95% CI] | mean [95% CI] |",
        "|---|---|---|---|",
    ]
    for name, entry in summary.items():
        for metric, title in METRICS.items():
            m = entry["metrics"][metric]
            iqm, mean = m["iqm"], m["mean"]
            lines.append(
                f"| {name} | {title} | {iqm[0]:.3g} [{iqm[1]:.3g}, {iqm[2]:.3g}] | "
                f"{mean[0]:.3g} [{mean[1]:.3g}, {mean[2]:.3g}] |"
            )
    for name, entry in summary.items():
        lines += ["", f"{name}, per seed (rows) and case (columns):", ""]
        lines.append("| metric | seed | " + " | ".join(entry["cases"]) + " |")
        lines.append("|---|---|" + "---|" * len(entry["cases"]))
        for metric, title in METRICS.items():
            for i, scores in enumerate(entry["metrics"][metric]["per_seed"]):
                cells = " | ".join(f"{v:.3g}" for v in scores)
                lines.append(f"| {title} | {i} | {cells} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.seeds", __doc__)
    ap.add_argument(
        "episodes", type=Path, nargs="+", help="evaluators' or ladders' episodes.csv (same seed)"
    )
    ap.add_argument("--group", action="append", required=True, metavar="NAME=POLICY,POLICY")
    ap.add_argument("--out", type=Path, default=Path("runs/seeds"))
    args = ap.parse_args(argv)
    groups = dict(parse_group(g) for g in args.group)
    summary = report([r for p in args.episodes for r in read_episodes(p)], groups)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "seeds.json").write_text(json.dumps(summary, indent=2) + "\n")
    text = markdown(summary)
    (args.out / "seeds.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
