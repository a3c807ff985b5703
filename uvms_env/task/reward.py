"""The shared team reward: computed once per step from the true object, same for every robot.

    r = progress + waypoint + success + violation + effort

* ``progress = w_progress * (Phi_prev - Phi)`` with the potential
  ``Phi = |p_O - p_wp| + w_attitude |wrap(Theta_O - Theta_wp)|`` of the true object
  towards the team's active waypoint (both terms towards the same waypoint, so passing
  a waypoint causes no jump). Potential-based: a detour that comes back earns nothing.
* ``waypoint = w_waypoint`` in the step the true object passes an intermediate
  waypoint (within ``WAYPOINT_TOLERANCE``; the team's own sequencer, in order).
* ``success = w_success`` in the step the episode succeeds.
* ``violation = -w_violation * (violated safety constraints summed over robots) / N
  - [the episode ends in failure: collision, a violation in "terminate" mode, or
  simulator divergence] * (w_failure + w_continuation * floor * remaining periods)``.
* ``effort = -w_effort * mean over robots and inputs of a^2`` (a normalized, clipped).

Ending early never pays: ``floor`` (``RewardWeights.period_floor``) is the most the
penalty terms can take in one period (every safety kind and extra constraint violated by
every robot, every input saturated), so with ``w_continuation = 1`` (the default) a
failure costs at least what the rest of the episode could have cost in violations and
effort, whatever the discount; ``0`` gives v0's one-off ``w_failure``. The progress term
is potential-based: its sum is the potential's drop to the episode's last state however
it ends, no cost of continuing.

The weights are ``RewardWeights`` (defaults below; pass ``reward_weights={...}`` to the
environment). The code that computes the reward over K environments is
``uvms_env.task.rules.Task.step``; extra terms: ``extra_reward_terms`` (see there).
May import: the standard library and ``uvms_env.task.constraints`` (the safety kinds).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from uvms_env.task.constraints import SAFETY_CONSTRAINTS

REWARD_TERMS = ("progress", "waypoint", "success", "violation", "effort")


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the reward terms (see module docstring)."""

    progress: float = 10.0  # per metre of potential decrease (~0.3 per step at 0.25 m/s)
    attitude: float = 0.5  # metres of potential per radian of attitude error
    waypoint: float = 5.0
    success: float = 50.0
    violation: float = 0.5  # per violated constraint, averaged over robots
    failure: float = 50.0
    effort: float = 0.05
    # the failure also pays the rest of the episode at ``period_floor`` times this
    continuation: float = 1.0

    def period_floor(self, extra_kinds: int = 0) -> float:
        """The most the violation and effort terms take in one period: every safety kind
        (and ``extra_kinds`` extra constraints) violated by every robot, their count per
        robot averaged, and every input saturated."""
        return self.violation * (len(SAFETY_CONSTRAINTS) + extra_kinds) + self.effort

    def failure_penalty(self, remaining: Any, extra_kinds: int = 0) -> Any:
        """What a failure costs with ``remaining`` periods left to the time limit (any
        array)."""
        return self.failure + self.continuation * self.period_floor(extra_kinds) * remaining

    @classmethod
    def from_mapping(cls, values: dict[str, float] | None) -> RewardWeights:
        """Defaults updated with ``values``; unknown names raise ValueError."""
        values = dict(values or {})
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ValueError(f"unknown reward weight(s) {unknown}; allowed: {names}")
        for key, value in values.items():
            if not math.isfinite(float(value)):
                raise ValueError(f"reward weight {key!r} must be finite, got {value}")
        return cls(**{k: float(v) for k, v in values.items()})
