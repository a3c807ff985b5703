"""Command-line pieces shared by the trainers, the imitation CLI and the evaluator:
``KEY=JSON`` options (``--env-option``, ``--hp``) and the conditions of the episodes
(``--n-agents``, ``--current``, ``--mismatch``), the same flag names in every command;
the periodic evaluations' flags of the trainers and DAgger (``--eval-*``).

Where training draws from a distribution, the condition flags take several values: team
sizes (each episode, or each group of environment copies, one of them), current presets
(each episode draws one) and a mismatch range (``--mismatch LOW HIGH``: each episode draws
one uniformly). They reach the environment as overrides and its ``randomize`` option
(``uvms_env.env.conditions``).

May import: the standard library and ``uvms_env.scenarios`` (the current presets).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from uvms_env.scenarios.overrides import CURRENT_PRESETS


def command_parser(prog: str, doc: str) -> argparse.ArgumentParser:
    """The parser of ``python -m PROG``: its module docstring ``doc`` as the description,
    as written, up to its "May import" line."""
    return argparse.ArgumentParser(
        prog=f"python -m {prog}",
        description=doc.split("May import")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


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


# flag -> (type, what one value is, what several values are), shared by every CLI
CONDITION_FLAGS: dict[str, tuple[Any, str, str]] = {
    "--n-agents": (int, "team size (random family)", "a set to draw from"),
    "--current": (str, "ocean current preset", "each episode draws one"),
    "--mismatch": (float, "model mismatch", "LOW HIGH: each episode draws one uniformly"),
}


def add_condition_arguments(g: Any, draws: bool = True) -> None:
    """``--n-agents``, ``--current`` and ``--mismatch``; ``draws``: each takes several
    values (a set of team sizes, of presets, a range), else one."""
    for flag, (kind, one, several) in CONDITION_FLAGS.items():
        g.add_argument(
            flag,
            type=kind,
            nargs="+" if draws else None,
            default=None,
            choices=CURRENT_PRESETS if flag == "--current" else None,
            metavar=None if flag == "--current" else flag[2].upper(),
            help=one + (f"; several: {several}" if draws else ""),
        )


def team_sizes(args: argparse.Namespace) -> tuple[int, ...]:
    """The team sizes of ``--n-agents`` (empty: the scenario's own)."""
    value = getattr(args, "n_agents", None)
    if value is None:
        return ()
    sizes = (value,) if isinstance(value, int) else tuple(value)
    return tuple(dict.fromkeys(int(n) for n in sizes))


def condition_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Environment keywords of ``--current`` and ``--mismatch``: one value an override,
    several a ``randomize`` draw (``uvms_env.env.conditions``). SystemExit on a malformed
    range."""
    out: dict[str, Any] = {}
    draws: dict[str, Any] = {}
    current = getattr(args, "current", None)
    if current is not None:
        presets = [current] if isinstance(current, str) else list(dict.fromkeys(current))
        if len(presets) == 1:
            out["current"] = presets[0]
        else:
            draws["current"] = presets
    mismatch = getattr(args, "mismatch", None)
    if mismatch is not None:
        values = [mismatch] if isinstance(mismatch, float | int) else list(mismatch)
        if len(values) == 1:
            out["mismatch"] = float(values[0])
        elif len(values) == 2 and values[0] <= values[1]:
            draws["mismatch"] = [float(v) for v in values]
        else:
            raise SystemExit(f"--mismatch takes one value or LOW HIGH, got {values}")
    if draws:
        out["randomize"] = draws
    return out


def add_evaluation_arguments(g: Any, episodes: int, episodes_help: str | None = None) -> None:
    """``--eval-episodes`` (default ``episodes``), ``--eval-seed`` and ``--eval-max-cycles``:
    the periodic evaluations of a training run (the RL trainers' and DAgger's)."""
    g.add_argument("--eval-episodes", type=int, default=episodes, help=episodes_help)
    g.add_argument("--eval-seed", type=int, default=None, help="their seed (default: --seed)")
    g.add_argument(
        "--eval-max-cycles",
        type=int,
        default=None,
        help="cap on the evaluation episodes and an RL run's final record (default: the "
        "scenarios' own length)",
    )
