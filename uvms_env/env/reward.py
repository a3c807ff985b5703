"""The shared team reward: computed once per step from the true object, same for every robot.

    r = progress + waypoint + success + violation + effort

* ``progress = w_progress * (Phi_prev - Phi)`` with the potential
  ``Phi = |p_O - p_wp| + w_attitude |wrap(Theta_O - Theta_wp)|`` of the true object
  towards the team's active waypoint (both terms towards the same waypoint, so passing
  a waypoint causes no jump). Potential-based: a detour that comes back earns nothing.
* ``waypoint = w_waypoint`` in the step the true object passes an intermediate
  waypoint (within ``WAYPOINT_TOLERANCE``; the team's own sequencer, in order).
* ``success = w_success`` in the step the episode succeeds.
* ``violation = -w_violation * (violated constraints summed over robots) / N
  - w_failure * [the episode ends in failure: collision, a violation in "terminate"
  mode, or simulator divergence]``.
* ``effort = -w_effort * mean over robots and inputs of a^2`` (a normalized, clipped).

The weights are ``RewardWeights`` (defaults below; pass ``reward_weights={...}`` to the
environment). May import: numpy, ``uvms_env.navigation``, ``uvms_env.scenarios`` (types),
``uvms_env.env.metrics`` and ``uvms_env.env.observation``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from uvms_env.env.metrics import goal_errors
from uvms_env.env.observation import WAYPOINT_TOLERANCE
from uvms_env.navigation import WaypointSequencer

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario

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


class TeamReward:
    """Shared reward and the team's waypoint sequencing on the true object."""

    def __init__(self, scenario: Scenario, weights: RewardWeights) -> None:
        self.weights = weights
        self.n = scenario.n_agents
        self.waypoints = np.asarray(scenario.waypoints, dtype=float)
        self.goal = self.waypoints[-1]
        self.pos_tol = scenario.success_pos_tol
        self.att_tol = scenario.success_att_tol
        self.sequencer = WaypointSequencer(self.waypoints, pos_tol=WAYPOINT_TOLERANCE)
        self._goal = self.goal.tolist()
        self._wp = self._goal
        self._potential = 0.0

    def potential(self, x_o: Sequence[float]) -> float:
        x, wp, tau = x_o, self._wp, math.tau
        att = math.hypot(
            math.remainder(x[3] - wp[3], tau),
            math.remainder(x[4] - wp[4], tau),
            math.remainder(x[5] - wp[5], tau),
        )
        return math.dist(x[:3], wp[:3]) + self.weights.attitude * att

    def at_goal(self, x_o: Sequence[float]) -> bool:
        if math.dist(x_o[:3], self._goal[:3]) >= self.pos_tol:
            return False  # the common case, decided cheaply
        pos, att = goal_errors(x_o, self._goal)
        return pos < self.pos_tol and att < self.att_tol

    def reset(self, x_o: np.ndarray) -> None:
        self.sequencer.reset()
        self.sequencer.update(x_o)
        self._wp = self.waypoints[self.sequencer.index].tolist()
        self._potential = self.potential(x_o)

    def __call__(
        self,
        x_o: Sequence[float],
        mean_sq_action: float,
        violated_count: float,
        success: bool,
        failed: bool,
    ) -> tuple[float, dict[str, float]]:
        """Reward of one step and its terms, from the true object pose after the step,
        the mean of the squared normalized (clipped) inputs over robots and inputs and
        the number of violated constraints summed over robots."""
        w = self.weights
        x = list(x_o)  # plain floats: this runs every step
        potential = self.potential(x)
        progress = w.progress * (self._potential - potential)
        passed = False
        if math.dist(x[:3], self._wp[:3]) < WAYPOINT_TOLERANCE:  # the sequencer decides
            before = self.sequencer.index
            self.sequencer.update(x)
            passed = self.sequencer.index != before
        if passed:
            self._wp = self.waypoints[self.sequencer.index].tolist()
            potential = self.potential(x)
        self._potential = potential
        terms = {
            "progress": progress,
            "waypoint": w.waypoint if passed else 0.0,
            "success": w.success if success else 0.0,
            # 0.0 - ...: a clean 0.0 rather than -0.0 when nothing is violated
            "violation": 0.0
            - w.violation * violated_count / self.n
            - (w.failure if failed else 0.0),
            "effort": 0.0 - w.effort * mean_sq_action,
        }
        return sum(terms.values()), terms
