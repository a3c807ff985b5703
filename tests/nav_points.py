"""One point at a time through the navigation fields, for the tests: the package evaluates
them in batches (and symbolically); these views read one row of the batch API, and
``twist`` is a waypoint navigator's reference at one pose."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uvms_env.navigation import NavigationField, WaypointNavigator, attitude_rate


def _row(p: ArrayLike) -> np.ndarray:
    return np.asarray(p, dtype=float).reshape(1, 3)


class PointField:
    """``field``'s batch functions at a single point ``p`` (3,); anything else is the
    field's own attribute."""

    def __init__(self, field: NavigationField) -> None:
        self.field = field

    def __getattr__(self, name: str) -> Any:
        return getattr(self.field, name)

    def log_phi(self, p: ArrayLike) -> float:
        return float(self.field.log_phi_batch(_row(p))[0])

    def phi(self, p: ArrayLike) -> float:
        return math.exp(self.log_phi(p))

    def grad_log_phi(self, p: ArrayLike) -> np.ndarray:
        return self.field.grad_log_phi_batch(_row(p))[0]

    def grad_phi(self, p: ArrayLike) -> np.ndarray:
        return self.field.grad_phi_batch(_row(p))[0]

    def desired_velocity(self, p: ArrayLike) -> np.ndarray:
        return self.field.desired_velocity_batch(_row(p))[0]

    def clearance(self, p: ArrayLike) -> float:
        return float(self.field.clearance_batch(_row(p))[0])


def twist(nav: WaypointNavigator, x_o: ArrayLike, index: int) -> np.ndarray:
    """The desired twist towards waypoint ``index`` at pose ``x_o`` (6,): the field's
    velocity and the attitude law's Euler-angle rates (what ``casadi_function`` builds)."""
    x = np.asarray(x_o, dtype=float)
    goal = nav.sequencer.waypoints[index]
    v = PointField(nav.fields[index]).desired_velocity(x[:3])
    w = attitude_rate(x[3:], goal[3:], nav.att_gain, nav.max_att_rate)
    return np.concatenate([v, w])
