"""The keyword options' schema: one table, key -> ``Option`` (type, range, meaning).

``SCENARIO_OVERRIDES`` lists the overrides of ``make`` (and of ``parallel_env``);
``validate_overrides`` checks and normalizes them, and ``Scenario``'s own validation checks
its fields with the same entries, so a range is written once; ``option_type`` reads a
command-line value against an entry (an argparse ``type``, for every command line).
Wrong types raise TypeError, values out of range ValueError; both name the key and state
what is allowed, and unknown keys raise ValueError listing every allowed key with its
range. Other option
groups (the environment's) build their tables from ``Option`` too.

No bools where numbers are expected (``True`` is not a team size) and no strings where
numbers are expected (``"3"`` is not 3); numpy scalars are accepted and normalized to
Python ``int``, ``float`` and ``bool``; floats must be finite.
"""

from __future__ import annotations

import argparse
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

# the random family's largest team; 7 and 8 are beyond the ladder's and the learned
# baselines' distribution (2..6): cases to measure generalization on
RANDOM_MAX_AGENTS = 8

CURRENT_PRESETS = ("none", "mild", "strong")
# The random family's objects and courses (uvms_env.scenarios.families.random).
RANDOM_OBJECTS = ("ring", "bar")
RANDOM_COURSES = ("open", "turns", "mixed")


@dataclass(frozen=True)
class Option:
    """One keyword option. ``kind``: "int", "float" (finite), "bool", "choice" (one of
    ``choices``), "weights" (a mapping name -> finite float; the names are checked by
    their consumer), "functions" (a mapping name -> callable or "module:function"
    string; imported and checked by their consumer), "comm" (the acoustic channel's
    settings, checked by ``uvms_env.robot.channel``) or "draws" (per-episode draws of the
    conditions, checked by ``uvms_env.task.conditions``). ``low``/``high`` bound numbers
    (inclusive unless ``*_open``); ``optional``: None is allowed too."""

    kind: str
    doc: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    optional: bool = False

    def describe(self) -> str:
        """What is allowed, e.g. ``float in [0, 0.5)``, ``int >= 1`` or ``None or int >= 0``."""
        if self.kind == "choice":
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        elif self.kind == "bool":
            text = "bool"
        elif self.kind == "weights":
            text = "dict name -> finite float"
        elif self.kind == "functions":
            text = "dict name -> callable or 'module:function'"
        elif self.kind == "comm":
            text = "'off', a preset name, a ChannelSettings or a dict"
        elif self.kind == "draws":
            text = "dict: current -> presets, mismatch -> [low, high]"
        else:
            text = f"{'finite float' if self.kind == 'float' else 'int'}{self._range()}"
        return f"None or {text}" if self.optional else text

    def _range(self) -> str:
        low, high = _num(self.low), _num(self.high)
        if self.low is not None and self.high is not None:
            if self.kind == "int":
                return f" in {low}..{high}"
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f" in {left}{low}, {high}{right}"
        if self.low is not None:
            return f" {'>' if self.low_open else '>='} {low}"
        if self.high is not None:
            return f" {'<' if self.high_open else '<='} {high}"
        return ""

    def check(self, name: str, value: Any) -> Any:
        """``value`` normalized (Python int/float/bool/str/dict); TypeError or ValueError
        naming ``name`` and what is allowed otherwise."""
        if value is None and self.optional:
            return None
        if self.kind == "choice":
            if not isinstance(value, str) or value not in self.choices:
                raise self._error(name, value, ValueError if isinstance(value, str) else TypeError)
            return str(value)
        if self.kind == "bool":
            if not isinstance(value, bool | np.bool_):
                raise self._error(name, value, TypeError)
            return bool(value)
        if self.kind == "weights":
            return self._check_weights(name, value)
        if self.kind == "functions":
            return self._check_functions(name, value)
        if self.kind in ("comm", "draws"):  # checked by their consumers (uvms_env.env)
            return value
        if isinstance(value, bool | np.bool_):
            raise self._error(name, value, TypeError)
        if self.kind == "int":
            if not isinstance(value, numbers.Integral):
                raise self._error(name, value, TypeError)
            value = int(value)
        else:
            if not isinstance(value, numbers.Real):
                raise self._error(name, value, TypeError)
            value = float(value)
            if not math.isfinite(value):
                raise self._error(name, value, ValueError)
        if not self._in_range(value):
            raise self._error(name, value, ValueError)
        return value

    def _in_range(self, x: float) -> bool:
        if self.low is not None and (x <= self.low if self.low_open else x < self.low):
            return False
        return self.high is None or (x < self.high if self.high_open else x <= self.high)

    def _check_weights(self, name: str, value: Any) -> dict[str, float]:
        if not isinstance(value, Mapping):
            raise self._error(name, value, TypeError)
        out = {}
        for key, w in value.items():
            what = f"{name}[{key!r}]: expected a finite float under a str key, got {w!r}"
            if not isinstance(key, str) or not isinstance(w, numbers.Real):
                raise TypeError(what)
            if isinstance(w, bool | np.bool_):
                raise TypeError(what)
            if not math.isfinite(float(w)):
                raise ValueError(what)
            out[key] = float(w)
        return out

    def _check_functions(self, name: str, value: Any) -> dict[str, Any]:
        if not isinstance(value, Mapping):
            raise self._error(name, value, TypeError)
        for key, fn in value.items():
            if not isinstance(key, str) or not (callable(fn) or isinstance(fn, str)):
                raise TypeError(
                    f"{name}[{key!r}]: expected a callable or 'module:function' under a str "
                    f"key, got {fn!r}"
                )
        return dict(value)

    def _error(self, name: str, value: Any, kind: type[Exception]) -> Exception:
        got = f"{value!r} ({type(value).__name__})"
        return kind(f"{name}: expected {self.describe()} ({self.doc}), got {got}")


SCENARIO_OVERRIDES: dict[str, Option] = {
    "current": Option("choice", "ocean current preset", choices=CURRENT_PRESETS),
    "damping_scale": Option("float", "multiplies all damping", low=0),
    "mismatch": Option(
        "float", "relative truth-model perturbation", low=0, high=0.5, high_open=True
    ),
    "sensor_noise": Option("float", "scale of the sensor-noise model, 0: perfect", low=0),
    "seed": Option("int", "scenario seed", low=0, optional=True),
    "max_steps": Option("int", "episode length in control periods", low=1),
    "substeps": Option("int", "RK4 substeps per control period", low=1),
    "success_pos_tol": Option(
        "float", "final-waypoint position tolerance, m", low=0, low_open=True
    ),
    "success_att_tol": Option(
        "float", "final-waypoint attitude tolerance, rad", low=0, low_open=True
    ),
    "n_agents": Option(
        "int",
        f"team size: random family 2..{RANDOM_MAX_AGENTS}, default 2; others 2",
        low=2,
        high=RANDOM_MAX_AGENTS,
    ),
    "object": Option(
        "choice",
        "random family: the carried object, a ring or a bar (one per team size), default ring",
        choices=RANDOM_OBJECTS,
    ),
    "course": Option(
        "choice",
        "random family: obstacles off the path (open, default), on it so that the path turns "
        "around them (turns), or either by seed (mixed)",
        choices=RANDOM_COURSES,
    ),
}
# The overrides a family interprets (they shape its geometry; not Scenario fields).
FAMILY_OPTIONS = ("n_agents", "object", "course")
# The overrides that are Scenario fields.
SCENARIO_FIELDS = tuple(k for k in SCENARIO_OVERRIDES if k not in FAMILY_OPTIONS)


def option_type(option: Option) -> Callable[[str], Any]:
    """An argparse ``type`` that reads a number and checks it against ``option`` (the
    environment's ``Option`` or one made here): out of range, argparse names the flag and
    what it accepts (``argument --robot-steps: expected int >= 1 (...), got -5``)."""

    kind = int if option.kind == "int" else float

    def parse(text: str) -> Any:
        try:
            value: Any = kind(text)
        except ValueError:
            value = text
        try:
            return option.check("value", value)
        except (TypeError, ValueError):
            doc = f" ({option.doc})" if option.doc else ""
            raise argparse.ArgumentTypeError(
                f"expected {option.describe()}{doc}, got {text!r}"
            ) from None

    return parse


def describe_options(table: Mapping[str, Option]) -> str:
    """``key (allowed values)`` for every key of a table, for error messages."""
    return ", ".join(f"{k} ({o.describe()})" for k, o in sorted(table.items()))


def validate_options(
    values: Mapping[str, Any], table: Mapping[str, Option], what: str
) -> dict[str, Any]:
    """``values`` checked against ``table`` and normalized; unknown keys raise ValueError
    listing the allowed ones (``what`` names the group, e.g. "scenario override")."""
    unknown = sorted(set(values) - set(table), key=str)
    if unknown:
        raise ValueError(f"unknown {what}(s) {unknown}; allowed: {describe_options(table)}")
    return {k: table[k].check(k, v) for k, v in values.items()}


def validate_overrides(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The scenario overrides of ``make``, checked and normalized (see the module doc)."""
    return validate_options(overrides, SCENARIO_OVERRIDES, "scenario override")


def _num(x: float | None) -> str:
    return f"{x:g}" if x is not None else ""
