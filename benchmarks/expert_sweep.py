"""The expert's sweep: the paper's controller and the offset-free one side by side.

    python benchmarks/expert_sweep.py --seed 2026 --out runs/expert_sweep
        [--sizes 2 3 4 5 6] [--episodes 10] [--paper-episodes 5] [--workers 1]
        [--policy nmpc:paper --policy nmpc] [--resume]

Cases: the random family at each team size N (``--episodes`` each) and the paper
scenario with the mild current and ``mismatch=0.1`` (``--paper-episodes``). Every case
is one ``baselines.evaluate`` run of all the policies on the same seeded episodes
(``case_episode_seed(seed, scenario, k)``), written to ``OUT/<case>/`` (episodes.csv,
results.json, results.md); ``--resume`` reuses a case whose results.json exists, so an
interrupted sweep continues. ``OUT/summary.md`` puts the cases side by side: success and
clean success (success with 0 violation periods) over the episodes whose current is
within the team's reach, those beyond it counted apart, violation periods by kind and
the decision time per robot.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

from baselines.command_line import non_negative_int, positive_int, script_parser, team_size
from baselines.evaluation.outputs import write_outputs
from baselines.evaluation.runner import evaluate
from baselines.evaluation.summary import VIOLATION_KINDS

PAPER_CASE = ("paper_mild_mismatch0.1", "paper", {"current": "mild", "mismatch": 0.1})


def cases(sizes: list[int]) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, scenario, overrides) of each case of the sweep."""
    return [(f"random_n{n}", "random", {"n_agents": n}) for n in sizes] + [PAPER_CASE]


def run_case(
    name: str,
    scenario: str,
    overrides: dict[str, Any],
    policies: list[str],
    episodes: int,
    seed: int,
    workers: int,
    out: Path,
    resume: bool,
) -> list[dict[str, Any]]:
    """The case's summaries (one per policy), from ``out/name`` when resuming."""
    folder = out / name
    done = folder / "results.json"
    if resume and done.exists():
        summaries = json.loads(done.read_text())
        if {s["policy"] for s in summaries} == set(policies) and all(
            s["episodes"] == episodes for s in summaries
        ):
            return summaries
    rows = evaluate(policies, [scenario], episodes, seed, workers, overrides, progress=False)
    return write_outputs(rows, seed, folder)


def summary_table(results: list[tuple[str, list[dict[str, Any]]]]) -> str:
    """Markdown: one row per (case, policy)."""

    def rate(s: dict[str, Any], key: str) -> str:
        n = s["episodes"] - s.get("out_of_reach", 0)
        return f"{round(s[key] * n)}/{n}" if n else "n/a"

    kinds = list(VIOLATION_KINDS)
    head = (
        "| case | policy | episodes | current out of reach | success | clean success | "
        + " | ".join(f"{k} periods" for k in kinds)
        + " | decision ms median / p95 |"
    )
    lines = [head, "|" + "---|" * (7 + len(kinds))]
    for case, summaries in results:
        for s in summaries:
            t = s["policy_time_ms"]
            lines.append(
                f"| {case} | {s['policy']} | {s['episodes']} | {s.get('out_of_reach', 0)} | "
                f"{rate(s, 'success_rate')} | {rate(s, 'clean_success_rate')} | "
                + " | ".join(str(s["violations"][k]) for k in kinds)
                + f" | {t['median']:.3f} / {t['p95']:.3f} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--seed", type=non_negative_int, default=2026)
    ap.add_argument("--sizes", type=team_size, nargs="+", default=[2, 3, 4, 5, 6])
    ap.add_argument("--episodes", type=positive_int, default=10, help="per random team size")
    ap.add_argument("--paper-episodes", type=positive_int, default=5)
    ap.add_argument("--no-paper", action="store_true", help="random family only")
    ap.add_argument("--policy", action="append", default=None, help="default: nmpc:paper, nmpc")
    ap.add_argument("--workers", type=positive_int, default=1)
    ap.add_argument("--out", type=Path, default=Path("runs/expert_sweep"))
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    policies = args.policy or ["nmpc:paper", "nmpc"]
    todo = cases(args.sizes)
    if args.no_paper:
        todo = todo[:-1]
    results = []
    for name, scenario, overrides in todo:
        episodes = args.paper_episodes if scenario == "paper" else args.episodes
        summaries = run_case(
            name,
            scenario,
            overrides,
            policies,
            episodes,
            args.seed,
            args.workers,
            args.out,
            args.resume,
        )
        results.append((name, summaries))
        table = summary_table(results)
        (args.out / "summary.md").write_text(table)  # after each case: partial results
        print(summary_table([(name, summaries)]), flush=True)
    print(table)
    print(f"wrote {args.out}/summary.md")


if __name__ == "__main__":
    main()
