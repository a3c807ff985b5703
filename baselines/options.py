"""Command-line pieces shared by the trainers and tools: ``KEY=JSON`` options
(``--env-option``, ``--hp``) and deprecated flag aliases.

May import: the standard library only.
"""

from __future__ import annotations

import argparse
import json
import warnings
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


class Deprecated(argparse.Action):
    """An old flag kept for one release: it stores into the new flag's destination and
    warns on stderr (hidden from ``--help``). ``ap.add_argument("--n-envs",
    action=Deprecated, dest="num_envs", new="--num-envs", type=int)``."""

    def __init__(self, option_strings: list[str], dest: str, new: str, **kwargs: Any) -> None:
        self.new = new
        kwargs.setdefault("help", argparse.SUPPRESS)
        kwargs.setdefault("default", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        warnings.warn(
            f"{option_string} is deprecated and will be removed in the next release; "
            f"use {self.new}",
            FutureWarning,
            stacklevel=2,
        )
        setattr(namespace, self.dest, values)


def add_deprecated(ap: Any, new: str, *old: str, **kwargs: Any) -> None:
    """Accept each ``old`` flag for ``new`` (same type), with a deprecation warning."""
    dest = new.lstrip("-").replace("-", "_")
    for flag in old:
        ap.add_argument(flag, action=Deprecated, dest=dest, new=new, **kwargs)
