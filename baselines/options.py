"""Command-line pieces shared by the trainers and tools: ``KEY=JSON`` options
(``--env-option``, ``--hp``).

May import: the standard library only.
"""

from __future__ import annotations

import json
from typing import Any


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
