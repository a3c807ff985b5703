"""The desired object twist along a waypoint list, built on navigation functions.

A mission is a list of object poses ``[x, y, z, phi, theta, psi]`` (position [m] and
ZYX Euler angles [rad]) visited in order; the last one is the goal.
:class:`WaypointSequencer` holds the validated list (which waypoint is active is the
task's rule: ``uvms_env.task.rules`` sequences them).  :class:`WaypointNavigator` builds one
:class:`~uvms_env.navigation.field.NavigationField` per waypoint (goal = waypoint
position) and, per waypoint, the symbolic desired object twist::

    twist_d = [v_d; dTheta_d/dt]        (6,)

* ``v_d`` (3,): the velocity reference of that waypoint's field, a linear velocity in the
  world frame [m/s];
* ``dTheta_d/dt`` (3,): **ZYX Euler-angle rates** [rad/s] (not a body angular velocity),
  from the attitude law (docs/model.md, "Navigation function";
  ``uvms_env.dynamics.spatial.euler_rate_matrix`` maps a body angular velocity to them).

Dependencies: this package may import numpy and casadi only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .field import (
    NAV_GAIN,
    NAV_MAX_SPEED,
    PAPER_K,
    NavigationField,
    Obstacle,
    Workspace,
    _attitude_rate_ca,
)

__all__ = ["WaypointNavigator", "WaypointSequencer"]

FloatArray = NDArray[np.float64]


def _as_waypoints(waypoints: ArrayLike) -> FloatArray:
    arr = np.asarray(waypoints, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 6 or arr.shape[0] == 0:
        raise ValueError(f"waypoints must have shape (N, 6) with N >= 1, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("waypoints must be finite (no NaN/inf)")
    return arr


class WaypointSequencer:
    """The mission's 6-D waypoints (N, 6), poses ``[x, y, z, phi, theta, psi]`` in order;
    the last one is the goal."""

    def __init__(self, waypoints: ArrayLike) -> None:
        self._waypoints = _as_waypoints(waypoints)

    @property
    def waypoints(self) -> FloatArray:
        """All waypoints (copy), shape (N, 6)."""
        return self._waypoints.copy()

    def __len__(self) -> int:
        return self._waypoints.shape[0]


class WaypointNavigator:
    """Desired object twist along a waypoint sequence, one navigation field per waypoint.

    ``waypoints`` (N, 6): their positions in the free space; ``workspace`` ...
    ``max_speed``: every :class:`NavigationField`'s; ``att_gain``: ``K_att`` [1/s] of the
    attitude law; ``max_att_rate``: the saturation of each Euler-angle rate [rad/s]."""

    def __init__(
        self,
        waypoints: ArrayLike,
        workspace: Workspace,
        obstacles: Sequence[Obstacle],
        team_radius: float,
        k: float = PAPER_K,
        gain: float = NAV_GAIN,
        max_speed: float = NAV_MAX_SPEED,
        att_gain: float = 0.2,
        max_att_rate: float = 0.05,
    ) -> None:
        self.sequencer = WaypointSequencer(waypoints)
        if not (math.isfinite(att_gain) and att_gain > 0.0):
            raise ValueError(f"att_gain must be positive and finite, got {att_gain}")
        if not (math.isfinite(max_att_rate) and max_att_rate > 0.0):
            raise ValueError(f"max_att_rate must be positive and finite, got {max_att_rate}")
        self._att_gain = float(att_gain)
        self._max_att_rate = float(max_att_rate)
        self.fields: tuple[NavigationField, ...] = tuple(
            NavigationField(wp[:3], workspace, obstacles, team_radius, k, gain, max_speed)
            for wp in self.sequencer.waypoints
        )

    @property
    def att_gain(self) -> float:
        """``K_att`` [1/s] of the attitude law."""
        return self._att_gain

    @property
    def max_att_rate(self) -> float:
        """Saturation of each Euler-angle rate [rad/s]."""
        return self._max_att_rate

    def casadi_function(self, index: int) -> ca.Function:
        """CasADi function ``nav_twist``: ``x`` (6x1) -> ``twist_d`` (6x1) for waypoint
        ``index`` (the switching logic stays outside the symbolic graph)."""
        i = self._check_index(index)
        x = ca.SX.sym("x", 6, 1)
        v = self.fields[i].casadi_velocity(x[0:3])
        goal_att = self.sequencer.waypoints[i][3:]
        w = _attitude_rate_ca(x[3:6], ca.DM(goal_att), self._att_gain, self._max_att_rate)
        return ca.Function("nav_twist", [x], [ca.vertcat(v, w)], ["x"], ["twist_d"])

    def _check_index(self, index: int) -> int:
        if not 0 <= index < len(self.sequencer):
            raise ValueError(f"waypoint index {index} out of range 0..{len(self.sequencer) - 1}")
        return int(index)
