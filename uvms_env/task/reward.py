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
  - w_failure * [the episode ends in failure: collision, a violation in "terminate"
  mode, or simulator divergence]``.
* ``effort = -w_effort * mean over robots and inputs of a^2`` (a normalized, clipped).

The weights are ``RewardWeights`` (defaults below; pass ``reward_weights={...}`` to the
environment). The code that computes the reward over K environments is
``uvms_env.task.rules.Task.step``; extra terms: ``extra_reward_terms`` (see there).
May import: the standard library only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

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
