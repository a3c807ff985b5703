"""The from-scratch audit's tables of training runs, from their ``evaluations.csv`` and
``progress.csv`` (``baselines.runs``' schemas):

    python -m baselines.rl.audit runs/ppo_a runs/ppo_b --out audit.md

* **Returns at the start and the end**: per run and evaluation rung, the mean return,
  success and clean success rates of the first and of the last evaluation, with their
  robot-steps (a rung's trivial policies, ``prior``, ``zero``, ``random``, come from
  ``baselines.evaluate`` on the same episodes; docs/rl.md).
* **What PPO optimizes and how episodes end**: per run, the mean episode objective
  (reward minus the Lagrangian's priced cost, ``episode_objective_mean``), the episode
  cost, the episode length, the multiplier and the share of episodes that ended early
  (diverged, collision, constraint) over the first and the last quarter of its training rows.

May import: the standard library, numpy, ``baselines.rl.plot`` (the CSV readers) and
``baselines.command_line``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.command_line import command_parser
from baselines.rl.plot import columns, read_rows

EARLY_ENDS = ("ends_diverged", "ends_collision", "ends_constraint")
ALL_ENDS = (*EARLY_ENDS, "ends_success", "ends_max_cycles")
QUARTER_MEANS = ("episode_objective_mean", "episode_cost_mean", "episode_len_mean", "multiplier")


def start_and_end(run: Path) -> list[dict[str, object]]:
    """Per rung of ``run``'s evaluations: its first and last evaluation's robot-steps,
    mean return, success and clean success rates."""
    rows = read_rows(run / "evaluations.csv")
    out = []
    for rung in dict.fromkeys(r["rung"] for r in rows):
        mine = [r for r in rows if r["rung"] == rung]
        first, last = mine[0], mine[-1]
        out.append(
            {
                "run": run.name,
                "rung": rung,
                **{f"{k}_{w}": _num(r[c]) for w, r in (("start", first), ("end", last))
                   for k, c in (("steps", "robot_steps"), ("return", "mean_return"),
                                ("success", "success_rate"), ("clean", "clean_success_rate"))},
            }
        )  # fmt: skip
    return out


def training_quarters(run: Path) -> dict[str, object] | None:
    """``run``'s objective, cost, multiplier and early-end share over the first and the
    last quarter of its progress rows (None without ``progress.csv`` rows)."""
    p = columns(read_rows(run / "progress.csv"))
    if not p or len(p.get("iteration", [])) == 0:
        return None
    n = len(p["iteration"])
    quarter = max(1, n // 4)
    out: dict[str, object] = {"run": run.name, "iterations": n}
    for name, part in (("first", slice(0, quarter)), ("last", slice(n - quarter, n))):
        for key in QUARTER_MEANS:
            values = p.get(key, np.full(n, np.nan))[part]
            out[f"{key}_{name}"] = float(np.nanmean(values)) if np.isfinite(values).any() else None
        ends = {k: float(np.nansum(p[k][part])) for k in ALL_ENDS if k in p}
        total = sum(ends.values())
        early = sum(ends.get(k, 0.0) for k in EARLY_ENDS)
        out[f"early_share_{name}"] = early / total if total else None
        out[f"episodes_{name}"] = int(total)
    return out


def markdown(runs: list[Path]) -> str:
    """Both tables of the module docstring for ``runs``."""
    lines = [
        "| run | rung | robot-steps | return | success | clean |",
        "|---|---|---|---|---|---|",
    ]
    for run in runs:
        for r in start_and_end(run):
            lines.append(
                f"| {r['run']} | {r['rung']} | {_fmt(r['steps_start'], 0)} -> "
                f"{_fmt(r['steps_end'], 0)} | {_fmt(r['return_start'])} -> "
                f"{_fmt(r['return_end'])} | {_fmt(r['success_start'], 2)} -> "
                f"{_fmt(r['success_end'], 2)} | {_fmt(r['clean_start'], 2)} -> "
                f"{_fmt(r['clean_end'], 2)} |"
            )
    lines += [
        "",
        "| run | iterations | objective | cost per robot-episode | episode periods | "
        "multiplier | ended early (episodes) |",
        "|---|---|---|---|---|---|---|",
    ]
    for run in runs:
        q = training_quarters(run)
        if q is None:
            continue
        lines.append(
            f"| {q['run']} | {q['iterations']} | {_fmt(q['episode_objective_mean_first'])} -> "
            f"{_fmt(q['episode_objective_mean_last'])} | {_fmt(q['episode_cost_mean_first'])}"
            f" -> {_fmt(q['episode_cost_mean_last'])} | {_fmt(q['episode_len_mean_first'], 0)}"
            f" -> {_fmt(q['episode_len_mean_last'], 0)} | {_fmt(q['multiplier_first'], 1)} -> "
            f"{_fmt(q['multiplier_last'], 1)} | {_share(q['early_share_first'])} "
            f"({q['episodes_first']}) -> {_share(q['early_share_last'])} "
            f"({q['episodes_last']}) |"
        )
    return "\n".join(lines) + "\n"


def _num(text: str | None) -> float | None:
    try:
        return float(text) if text not in (None, "") else None
    except ValueError:
        return None


def _fmt(x: object, digits: int = 1) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return f"{float(x):,.{digits}f}"  # type: ignore[arg-type]


def _share(x: object) -> str:
    return "-" if x is None else f"{float(x):.0%}"  # type: ignore[arg-type]


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.rl.audit", __doc__)
    ap.add_argument("runs", type=Path, nargs="+", help="run folders")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here")
    args = ap.parse_args(argv)
    missing = [str(r) for r in args.runs if not (r / "config.json").exists()]
    if missing:
        ap.error(f"not a run folder (no config.json): {', '.join(missing)}")
    text = markdown(args.runs)
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
