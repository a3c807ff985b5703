"""Per-episode draws of the conditions a team works in: the ocean current and the model
mismatch (domain randomization, for training on a distribution of conditions).

    env = uvms_env.parallel_env("random", randomize={"current": ["none", "mild"],
                                                     "mismatch": [0.0, 0.15]})

A key left out keeps the scenario's value. The draws come from a generator of their own,
keyed by the episode's truth-model seed, so every other draw of the episode is what it is
without ``randomize`` (docs/environment.md, "Conditions drawn per episode").

May import: numpy and ``uvms_env.scenarios`` (the presets and the mismatch range).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from uvms_env.scenarios.overrides import CURRENT_PRESETS, SCENARIO_OVERRIDES

KEYS = ("current", "mismatch")
# a fixed word mixed into each episode's seed: the draws' own stream
_STREAM = 0x5EED_C0DE


@dataclass(frozen=True)
class Conditions:
    """One episode's conditions: the current preset and the mismatch."""

    current: str
    mismatch: float


@dataclass(frozen=True)
class ConditionDraws:
    """What ``randomize`` draws from: current presets (None: the scenario's) and a
    mismatch range [low, high] (None: the scenario's)."""

    currents: tuple[str, ...] | None = None
    mismatch: tuple[float, float] | None = None

    def draw(self, seed: int, base: Conditions) -> Conditions:
        """The conditions of the episode whose truth-model seed is ``seed``; what is not
        drawn is ``base``'s."""
        rng = np.random.default_rng([int(seed) % 2**63, _STREAM])
        current = base.current
        if self.currents is not None:
            current = self.currents[int(rng.integers(len(self.currents)))]
        mismatch = base.mismatch
        if self.mismatch is not None:
            low, high = self.mismatch
            mismatch = float(rng.uniform(low, high)) if high > low else low
        return Conditions(current, mismatch)

    def describe(self) -> dict[str, Any]:
        """The draws as the option takes them (for records)."""
        out: dict[str, Any] = {}
        if self.currents is not None:
            out["current"] = list(self.currents)
        if self.mismatch is not None:
            out["mismatch"] = list(self.mismatch)
        return out


def condition_draws(value: Any) -> ConditionDraws | None:
    """The ``randomize`` option checked: None, or a mapping with ``current`` (a preset
    name or a non-empty list of them) and/or ``mismatch`` (a number or [low, high] within
    the mismatch override's range). TypeError or ValueError naming the problem."""
    if value is None:
        return None
    if isinstance(value, ConditionDraws):
        return value
    if not isinstance(value, Mapping):
        raise TypeError(
            f"randomize must be None or a dict with keys {KEYS}, got {type(value).__name__}"
        )
    unknown = sorted(set(value) - set(KEYS), key=str)
    if unknown:
        raise ValueError(f"randomize: unknown key(s) {unknown}; allowed: {list(KEYS)}")
    currents = None
    if "current" in value:
        raw = value["current"]
        names = [raw] if isinstance(raw, str) else raw
        if not isinstance(names, Sequence) or not names:
            raise TypeError(
                f"randomize['current'] must be a preset name or a non-empty list of "
                f"{CURRENT_PRESETS}, got {raw!r}"
            )
        for name in names:
            SCENARIO_OVERRIDES["current"].check("randomize['current']", name)
        currents = tuple(str(n) for n in names)
    mismatch = None
    if "mismatch" in value:
        mismatch = _range("randomize['mismatch']", value["mismatch"])
    if currents is None and mismatch is None:
        return None
    return ConditionDraws(currents, mismatch)


def _range(name: str, raw: Any) -> tuple[float, float]:
    """A number m (the range [m, m]) or [low, high], each a valid mismatch."""
    check = SCENARIO_OVERRIDES["mismatch"].check
    if isinstance(raw, numbers.Real) and not isinstance(raw, bool):
        m = check(name, raw)
        return (m, m)
    if not isinstance(raw, Sequence) or isinstance(raw, str) or len(raw) != 2:
        raise TypeError(f"{name} must be a number or [low, high], got {raw!r}")
    low, high = (check(name, v) for v in raw)
    if not (math.isfinite(low) and low <= high):
        raise ValueError(f"{name} must have low <= high, got {list(raw)}")
    return (low, high)
