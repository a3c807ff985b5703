"""Command-line pieces shared by every command of ``baselines``: the parser (``python -m
PROG`` in its usage, no prefix abbreviations), the argparse types that check a value as it
is parsed (counts, budgets, seeds, the conditions in the environment's own words, paths
that must exist, ``KEY=JSON``), ``usage_errors`` (a refused value is a usage error, exit 2,
never a traceback), ``KEY=JSON`` options (``--env-option``, ``--hp``) and the conditions of
the episodes (``--n-agents``, ``--current``, ``--mismatch``), the same flag names in every
command; the periodic evaluations' flags of the trainers and DAgger (``--eval-*``).

Where training draws from a distribution, the condition flags take several values: team
sizes (each episode, or each group of environment copies, one of them), current presets
(each episode draws one) and a mismatch range (``--mismatch LOW HIGH``: each episode draws
one uniformly). They reach the environment as overrides and its ``randomize`` option
(``uvms_env.task.conditions``).

May import: the standard library and ``uvms_env.scenarios`` (the families, the current
presets and the overrides' table, whose ranges and wording the types reuse).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from uvms_env.scenarios.families import FAMILIES
from uvms_env.scenarios.overrides import CURRENT_PRESETS, SCENARIO_OVERRIDES, Option, option_type

SCENARIOS = tuple(FAMILIES)  # ``--scenario``'s choices


def command_parser(
    prog: str, doc: str | None, command: str = "python -m "
) -> argparse.ArgumentParser:
    """The parser of ``python -m PROG``: its module docstring ``doc`` as the description,
    as written, up to its "May import" line; a flag must be spelt out (``--n-agent`` is
    no ``--n-agents``)."""
    return argparse.ArgumentParser(
        prog=f"{command}{prog}",
        description=(doc or "").split("May import")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )


@contextmanager
def usage_errors(
    ap: argparse.ArgumentParser, kinds: tuple[type[Exception], ...] = (ValueError, TypeError)
) -> Iterator[None]:
    """An exception of ``kinds`` raised inside (a check of the command line, in the words
    of the code that refuses the value) becomes ``ap.error``: exit 2, no traceback."""
    try:
        yield
    except kinds as exc:
        ap.error(str(exc))


# -- argparse types: a value is checked as it is parsed (``option_type``) ----------------
positive_int = option_type(Option("int", "", low=1))
# 0: "none" where a flag says so; seeds too (the environment takes none below 0)
non_negative_int = option_type(Option("int", "", low=0))
positive_float = option_type(Option("float", "", low=0, low_open=True))
non_negative_float = option_type(Option("float", "", low=0))
fraction = option_type(Option("float", "", low=0, high=1))


def existing_path(text: str) -> Path:
    """An argparse ``type``: a file or folder that exists."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"no such file or folder: {text}")
    return path


def key_value(text: str) -> str:
    """An argparse ``type`` for ``KEY=JSON`` (read by ``key_value_pairs``)."""
    key, sep, _ = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return text


def script_parser(path: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of a script run as ``python FOLDER/NAME.py`` (the benchmarks): as
    ``command_parser``'s."""
    here = Path(path)
    return command_parser(f"{here.parent.name}/{here.name}", doc, command="python ")


def key_value_pairs(items: list[str]) -> dict[str, Any]:
    """``["a=1", "b=\\"x\\"", "c=plain"]`` -> {a: 1, b: "x", c: "plain"}: each value parsed
    as JSON, kept as text when it is not JSON."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"expected KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


# the conditions' values, checked against the environment's own table of overrides
team_size = option_type(SCENARIO_OVERRIDES["n_agents"])
model_mismatch = option_type(SCENARIO_OVERRIDES["mismatch"])

object_kind = option_type(SCENARIO_OVERRIDES["object"])
course_kind = option_type(SCENARIO_OVERRIDES["course"])

# flag -> (type, what one value is, what several values are; None: one value only), shared
# by every CLI
CONDITION_FLAGS: dict[str, tuple[Any, str, str | None]] = {
    "--n-agents": (team_size, "team size (random family)", "one group of env copies each"),
    "--object": (object_kind, "the random family's object: ring or bar", "one group each"),
    "--course": (course_kind, "the random family's course: open, turns or mixed", None),
    "--current": (str, "ocean current preset", "each episode draws one"),
    "--mismatch": (model_mismatch, "model mismatch", "LOW HIGH: each episode draws one uniformly"),
}


NAMES = {"--object": "OBJECT", "--course": "COURSE"}  # metavars (the others: a letter)


def add_condition_arguments(g: Any, draws: bool = True) -> None:
    """``--n-agents``, ``--object``, ``--course``, ``--current`` and ``--mismatch``;
    ``draws``: those that can take several values (a set of team sizes, of objects, of
    presets, a range) do, else one."""
    for flag, (kind, one, several) in CONDITION_FLAGS.items():
        many = draws and several is not None
        g.add_argument(
            flag,
            type=kind,
            nargs="+" if many else None,
            default=None,
            choices=CURRENT_PRESETS if flag == "--current" else None,
            metavar=None if flag == "--current" else NAMES.get(flag, flag[2].upper()),
            help=one + (f"; several: {several}" if many else ""),
        )


def team_sizes(args: argparse.Namespace) -> tuple[int, ...]:
    """The team sizes of ``--n-agents`` (empty: the scenario's own)."""
    return tuple(dict.fromkeys(int(n) for n in _given(args, "n_agents")))


def objects(args: argparse.Namespace) -> tuple[str, ...]:
    """The objects of ``--object`` (empty: the scenario's own)."""
    return _given(args, "object")


def _given(args: argparse.Namespace, name: str) -> tuple[Any, ...]:
    """The values of a condition flag that takes one value or several, once each, in the
    order given (empty: not given)."""
    value = getattr(args, name, None)
    if value is None:
        return ()
    return tuple(dict.fromkeys(value if isinstance(value, list | tuple) else [value]))


def team_variants(sizes: tuple[int, ...], kinds: tuple[str, ...]) -> list[dict[str, Any]]:
    """The environment keywords of each team size and object of a run, team size outer
    (``n_agents``, ``object``; one empty dict where neither was given)."""
    out = []
    for n in sizes or (None,):
        for kind in kinds or (None,):
            variant: dict[str, Any] = {} if n is None else {"n_agents": n}
            if kind is not None:
                variant["object"] = kind
            out.append(variant)
    return out


def condition_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Environment keywords of ``--course``, ``--current`` and ``--mismatch``: one value an
    override, several a ``randomize`` draw (``uvms_env.task.conditions``). ValueError,
    naming the flag, on a malformed range."""
    out: dict[str, Any] = {}
    if getattr(args, "course", None) is not None:
        out["course"] = args.course
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
            raise ValueError(f"--mismatch takes one value or LOW HIGH, got {values}")
    if draws:
        out["randomize"] = draws
    return out


def add_evaluation_arguments(g: Any, episodes: int, episodes_help: str | None = None) -> None:
    """``--eval-episodes`` (default ``episodes``), ``--eval-seed`` and ``--eval-max-cycles``:
    the periodic evaluations of a training run (the RL trainers' and DAgger's)."""
    g.add_argument("--eval-episodes", type=non_negative_int, default=episodes, help=episodes_help)
    g.add_argument(
        "--eval-seed", type=non_negative_int, default=None, help="their seed (default: --seed)"
    )
    g.add_argument(
        "--eval-max-cycles",
        type=positive_int,
        default=None,
        help="cap on the evaluation episodes and an RL run's final record (default: the "
        "scenarios' own length)",
    )


def add_batch_argument(g: Any) -> None:
    """``--batch K``: a per-robot policy's episodes of a case K at a time through the
    batched environment (``baselines.evaluation.batched``)."""
    g.add_argument(
        "--batch",
        type=non_negative_int,
        default=0,
        metavar="K",
        help="play each per-robot policy's episodes of a case K at a time in one batched "
        "environment per worker (0: one by one; team policies, the channel and replays "
        "always play one by one): the same episodes, their numbers equal to ~1e-6 over "
        "hundreds of periods, but a marginal episode can end otherwise over thousands; "
        "play every rung of one table alike",
    )
