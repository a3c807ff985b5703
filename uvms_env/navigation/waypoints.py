"""Waypoint sequencing and the desired object twist built on navigation functions.

A mission is a list of object poses ``[x, y, z, phi, theta, psi]`` (position [m] and
ZYX Euler angles [rad]) visited in order; the last one is the goal.
:class:`WaypointSequencer` keeps the index of the active waypoint and advances it when the
object is close enough.  :class:`WaypointNavigator` builds one
:class:`~uvms_env.navigation.field.NavigationField` per waypoint (goal = waypoint
position) and returns the desired object twist for the active waypoint::

    twist_d = [v_d; dTheta_d/dt]        (6,)

* ``v_d`` (3,): :meth:`NavigationField.desired_velocity` of the active waypoint, a
  linear velocity in the world frame [m/s];
* ``dTheta_d/dt`` (3,): **ZYX Euler-angle rates** [rad/s] (not a body angular velocity),
  from :func:`~uvms_env.navigation.field.attitude_rate`; use
  :func:`euler_rates_to_body_rates` to convert.

Dependencies: this package may import numpy and casadi only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .field import (
    NavigationField,
    Obstacle,
    Workspace,
    _as_vector,
    _attitude_rate_ca,
    attitude_rate,
    wrap_angle,
)

__all__ = ["WaypointNavigator", "WaypointSequencer", "euler_rates_to_body_rates"]

FloatArray = NDArray[np.float64]


def _as_waypoints(waypoints: ArrayLike) -> FloatArray:
    arr = np.asarray(waypoints, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 6 or arr.shape[0] == 0:
        raise ValueError(f"waypoints must have shape (N, 6) with N >= 1, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("waypoints must be finite (no NaN/inf)")
    return arr


def euler_rates_to_body_rates(attitude: ArrayLike, rates: ArrayLike) -> FloatArray:
    """Convert ZYX Euler-angle rates into the body-frame angular velocity.

    With ``R = Rz(psi) Ry(theta) Rx(phi)``:
    ``p = dphi - sin(theta) dpsi``,
    ``q = cos(phi) dtheta + sin(phi) cos(theta) dpsi``,
    ``r = -sin(phi) dtheta + cos(phi) cos(theta) dpsi``.

    Parameters
    ----------
    attitude : array_like, shape (3,)
        ZYX Euler angles ``(phi, theta, psi)`` [rad].
    rates : array_like, shape (3,)
        Their time derivatives [rad/s].

    Returns
    -------
    numpy.ndarray, shape (3,)
        Angular velocity in the body frame [rad/s].
    """
    phi, theta, _ = _as_vector("attitude", attitude, 3)
    dphi, dtheta, dpsi = _as_vector("rates", rates, 3)
    sp, cp = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    return np.array([dphi - st * dpsi, cp * dtheta + sp * ct * dpsi, -sp * dtheta + cp * ct * dpsi])


class WaypointSequencer:
    """Visits 6-D waypoints in order; the last one is the goal.

    The active waypoint is passed when the position error is below ``pos_tol`` and, if
    ``att_tol`` is given, the largest wrapped Euler-angle error is below ``att_tol``.
    At most one waypoint is passed per :meth:`update`.  Passing the last waypoint sets
    :attr:`done`; the index then stays on the last waypoint.

    Parameters
    ----------
    waypoints : array_like, shape (N, 6)
        Poses ``[x, y, z, phi, theta, psi]``.
    pos_tol : float
        Position tolerance [m], positive.
    att_tol : float or None
        Attitude tolerance [rad], positive, or ``None`` to ignore the attitude.
    """

    def __init__(
        self, waypoints: ArrayLike, pos_tol: float = 0.3, att_tol: float | None = None
    ) -> None:
        self._waypoints = _as_waypoints(waypoints)
        if not (math.isfinite(pos_tol) and pos_tol > 0.0):
            raise ValueError(f"pos_tol must be positive and finite, got {pos_tol}")
        if att_tol is not None and not (math.isfinite(att_tol) and att_tol > 0.0):
            raise ValueError(f"att_tol must be positive and finite or None, got {att_tol}")
        self._pos_tol = float(pos_tol)
        self._att_tol = None if att_tol is None else float(att_tol)
        self._index = 0
        self._done = False

    @property
    def waypoints(self) -> FloatArray:
        """All waypoints (copy), shape (N, 6)."""
        return self._waypoints.copy()

    @property
    def index(self) -> int:
        """Index of the active waypoint."""
        return self._index

    @property
    def current(self) -> FloatArray:
        """Active waypoint (copy), shape (6,)."""
        return self._waypoints[self._index].copy()

    @property
    def done(self) -> bool:
        """Whether the last waypoint has been reached."""
        return self._done

    def __len__(self) -> int:
        return self._waypoints.shape[0]

    def reset(self) -> None:
        """Restart from the first waypoint."""
        self._index = 0
        self._done = False

    def reached(self, x_o: ArrayLike) -> bool:
        """Whether pose ``x_o`` (6,) is within tolerance of the active waypoint."""
        x = _as_vector("x_O", x_o, 6)
        wp = self._waypoints[self._index]
        if np.linalg.norm(x[:3] - wp[:3]) >= self._pos_tol:
            return False
        if self._att_tol is None:
            return True
        return bool(np.max(np.abs(wrap_angle(x[3:] - wp[3:]))) < self._att_tol)

    def update(self, x_o: ArrayLike) -> int:
        """Advance past the active waypoint if ``x_o`` reached it.

        Parameters
        ----------
        x_o : array_like, shape (6,)
            Object pose ``[x, y, z, phi, theta, psi]``.

        Returns
        -------
        int
            Index of the active waypoint after the update.
        """
        if not self._done and self.reached(x_o):
            if self._index + 1 < len(self):
                self._index += 1
            else:
                self._done = True
        return self._index


class WaypointNavigator:
    """Desired object twist along a waypoint sequence, one navigation field per waypoint.

    Parameters
    ----------
    waypoints : array_like, shape (N, 6)
        Poses ``[x, y, z, phi, theta, psi]``; positions must be in the free space.
    workspace, obstacles, team_radius, k, gain, max_speed
        Passed to every :class:`NavigationField`.
    att_gain : float
        ``K_att`` [1/s] of the attitude law.
    max_att_rate : float
        Saturation of each Euler-angle rate [rad/s].
    pos_tol, att_tol : float, float or None
        Switching tolerances of the :class:`WaypointSequencer`.
    """

    def __init__(
        self,
        waypoints: ArrayLike,
        workspace: Workspace,
        obstacles: Sequence[Obstacle],
        team_radius: float,
        k: float = 6.0,
        gain: float = 0.5,
        max_speed: float = 0.25,
        att_gain: float = 0.2,
        max_att_rate: float = 0.05,
        pos_tol: float = 0.3,
        att_tol: float | None = None,
    ) -> None:
        self.sequencer = WaypointSequencer(waypoints, pos_tol=pos_tol, att_tol=att_tol)
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

    def twist(self, x_o: ArrayLike, index: int | None = None) -> FloatArray:
        """Desired twist towards waypoint ``index`` (default: the active one), no switching.

        Parameters
        ----------
        x_o : array_like, shape (6,)
            Object pose ``[x, y, z, phi, theta, psi]``.
        index : int or None
            Waypoint index.

        Returns
        -------
        numpy.ndarray, shape (6,)
            ``[v_d (world frame, m/s); ZYX Euler-angle rates (rad/s)]``.
        """
        x = _as_vector("x_O", x_o, 6)
        i = self.sequencer.index if index is None else self._check_index(index)
        wp = self.sequencer.waypoints[i]
        v = self.fields[i].desired_velocity(x[:3])
        w = attitude_rate(x[3:], wp[3:], self._att_gain, self._max_att_rate)
        return np.concatenate([v, w])

    def reference_twist(self, x_o: ArrayLike) -> FloatArray:
        """Update the sequencer with ``x_o``, then return :meth:`twist` for the active one.

        Parameters
        ----------
        x_o : array_like, shape (6,)
            Object pose ``[x, y, z, phi, theta, psi]``.

        Returns
        -------
        numpy.ndarray, shape (6,)
            ``[v_d (world frame, m/s); ZYX Euler-angle rates (rad/s)]``.
        """
        self.sequencer.update(x_o)
        return self.twist(x_o)

    def casadi_function(self, index: int) -> ca.Function:
        """CasADi function ``nav_twist``: ``x`` (6x1) -> ``twist_d`` (6x1) for waypoint ``index``.

        Parameters
        ----------
        index : int
            Waypoint index (the switching logic stays outside the symbolic graph).

        Returns
        -------
        casadi.Function
        """
        i = self._check_index(index)
        x = ca.SX.sym("x", 6, 1)
        v = self.fields[i].casadi_velocity(x[0:3])
        goal_att = self.sequencer.waypoints[i][3:]
        w = _attitude_rate_ca(x[3:6], goal_att, self._att_gain, self._max_att_rate)
        return ca.Function("nav_twist", [x], [ca.vertcat(v, w)], ["x"], ["twist_d"])

    def _check_index(self, index: int) -> int:
        if not 0 <= index < len(self.sequencer):
            raise ValueError(f"waypoint index {index} out of range 0..{len(self.sequencer) - 1}")
        return int(index)
