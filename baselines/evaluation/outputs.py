"""An evaluation's files, and the run-and-write sequence every command shares.

``write_outputs`` writes the evaluator's ``episodes.csv`` (one row per episode),
``results.json`` (``aggregate``), ``results.md`` and plots; ``read_episodes`` reads an
``episodes.csv`` back. ``run_and_write`` is what the evaluator, the ladder and the channel
sweep each do: evaluate, pool the rows, write the evaluator's outputs; ``write_result``
puts a command's own result (``ladder.*``, ``sweep.*``) beside them with its settings.

May import: the standard library and ``baselines.evaluation``'s ``runner``, ``summary``
and ``report``.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from baselines.evaluation.report import failure_lines, markdown_table, write_plots
from baselines.evaluation.runner import Case, Settings
from baselines.evaluation.summary import aggregate

Row = dict[str, Any]
# what one evaluation plays: policies on cases (names or ``Case``s)
Play = tuple[Sequence[str], Sequence[str | Case]]


def write_outputs(rows: list[Row], seed: int, out: Path) -> list[Row]:
    """``episodes.csv``, ``results.json``, ``results.md`` and the plots in ``out``; the
    summaries (``aggregate``)."""
    out.mkdir(parents=True, exist_ok=True)
    summaries = aggregate(rows, seed)
    keys = list(
        dict.fromkeys(k for r in rows for k in r if not k.startswith("_") and k != "traceback")
    )
    with open(out / "episodes.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, restval="", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    (out / "results.json").write_text(json.dumps(summaries, indent=2))
    (out / "results.md").write_text(markdown_table(summaries, failure_lines(rows)))
    write_plots(rows, summaries, out)
    return summaries


def read_episodes(path: Path) -> list[Row]:
    """``write_outputs``' episodes.csv back as rows: booleans and numbers typed, empty
    cells None, ``error`` "" when absent (the per-decision times are not in the file, only
    each episode's summary ``policy_time_ms_*``)."""

    def typed(value: str) -> Any:
        if value in ("True", "False"):
            return value == "True"
        if value == "":
            return None
        try:
            return float(value)
        except ValueError:
            return value

    with open(path, newline="") as fh:
        rows = [{k: typed(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    for r in rows:
        r["episode"] = int(r["episode"])
        r["error"] = r.get("error") or ""
    return rows


def run_and_write(
    settings: Settings, plays: Sequence[Play], out: Path
) -> tuple[list[Row], list[Row]]:
    """Each play evaluated with ``settings``, the rows pooled (in the plays' order) and the
    evaluator's outputs written to ``out``: the rows and their summaries. The policies
    whose episodes failed are named on the console too, with their first error."""
    rows = [row for policies, cases in plays for row in settings.evaluate(policies, cases)]
    summaries = write_outputs(rows, settings.seed, out)
    for line in failure_lines(rows):
        print(f"failed: {line}", flush=True)
    return rows, summaries


def write_result(out: Path, name: str, result: dict[str, Any], text: str, command: dict) -> None:
    """A command's own result in ``out``: ``result`` with its ``command`` (the settings it
    ran with) as ``NAME.json``, ``text`` as ``NAME.md``."""
    result["command"] = command
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(result, indent=2, default=str))
    (out / f"{name}.md").write_text(text)
