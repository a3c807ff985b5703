"""Command-line pieces shared by the trainers and tools: ``KEY=JSON`` options
(``--env-option``, ``--hp``).

May import: the standard library only.
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def add_option_arguments(ap: argparse.ArgumentParser, hp_help: str) -> None:
    """The trainers' ``--env-option`` and ``--hp`` (repeatable ``KEY=JSON``)."""
    ap.add_argument(
        "--env-option",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="environment option, e.g. max_cycles=200 or reward_weights='{\"effort\": 0.01}'",
    )
    ap.add_argument("--hp", action="append", default=[], metavar="KEY=JSON", help=hp_help)


def key_value_pairs(items: list[str]) -> dict[str, Any]:
    """``["a=1", "b=\\"x\\"", "c=plain"]`` -> {a: 1, b: "x", c: "plain"}: each value parsed
    as JSON, kept as text when it is not JSON."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"expected KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out
