"""The object reference over the horizon, from the navigation function (paper eq8-eq9).

Each robot propagates the desired object motion from its *own* estimate of the object
pose (paper: consensus without communication, since every estimate agrees under a rigid
grasp): x^d_0 = x_O estimate, x^d_{k+1} = x^d_k + h [v_d(x^d_k); Theta_dot_d(x^d_k)]
(explicit Euler, h = the sampling time), and v^d_k = [v_d; omega_d] with omega_d the
inertial angular velocity of the desired Euler-angle rates.

Attitude (default ``attitude_from_waypoint``): the pose reference's Euler angles are the
active waypoint's, not the propagated ones (why: docs/expert.md, "OCP"). The twist
reference keeps the navigation law's rates.

The propagation is one small CasADi function per waypoint, evaluated through the
zero-copy buffer interface (no compilation, so a new scenario costs nothing).
``AttitudeSlew``: that attitude reached at a bounded rate (a long object's turn).
``GoalIntegral``: the integral action near the last waypoint that both the distributed
expert and the centralized NMPC apply to this reference.

May import: numpy, casadi, ``nmpc_expert.settings``, ``uvms_env.navigation`` and
``uvms_env.dynamics``.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from nmpc_expert.settings import NMPCSettings
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.dynamics.spatial import rot_zyx, wrap_angle
from uvms_env.navigation import WaypointNavigator


def euler_rates_to_inertial(theta: cs.SX, rates: cs.SX) -> cs.SX:
    """omega (inertial) = R(Theta) W(Theta) Theta_dot, W = T^-1 (ZYX)."""
    sf, cf = cs.sin(theta[0]), cs.cos(theta[0])
    st, ct = cs.sin(theta[1]), cs.cos(theta[1])
    body = cs.vertcat(
        rates[0] - st * rates[2],
        cf * rates[1] + sf * ct * rates[2],
        -sf * rates[1] + cf * ct * rates[2],
    )
    return rot_zyx(theta) @ body


class HorizonReference:
    """x^d (6 x N+1) and v^d (6 x N+1) over the horizon for each waypoint of a mission."""

    def __init__(
        self,
        navigator: WaypointNavigator,
        horizon: int,
        period: float,
        attitude_from_waypoint: bool = True,
    ) -> None:
        self.navigator = navigator
        self.horizon = horizon
        self._calls: list[BufferCall] = []
        for index in range(len(navigator.sequencer)):
            twist = navigator.casadi_function(index)
            x0 = cs.SX.sym("x0", 6)
            goal_att = cs.DM(navigator.sequencer.waypoints[index][3:])
            xs, vs = [], []
            xk = x0
            for _ in range(horizon + 1):
                tw = twist(xk)
                vs.append(cs.vertcat(tw[:3], euler_rates_to_inertial(xk[3:], tw[3:])))
                xs.append(cs.vertcat(xk[:3], goal_att) if attitude_from_waypoint else xk)
                xk = xk + period * tw
            fn = cs.Function(
                f"nmpc_reference_{index}", [x0], [cs.horzcat(*xs[: horizon + 1]), cs.horzcat(*vs)]
            )
            self._calls.append(BufferCall(fn))
        self._x0 = np.zeros(6)

    def __call__(self, x_o: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(x^d, v^d), each (N+1, 6) (row k = node k), from the object estimate ``x_o``."""
        self._x0[:] = x_o
        xd, vd = self._calls[index](self._x0)
        return xd, vd


class AttitudeSlew:
    """The pose reference's attitude moved toward the active waypoint's at no more than
    ``rate`` rad/s per Euler angle (``NMPCSettings.attitude_tip_speed``), and the twist
    reference's angular speed capped at ``rate``: node k of a decision asks for
    a + clip(wrap(goal - a), +-rate k h), a the slewed attitude, which then advances one
    period. ``a`` starts at the object's estimated attitude at the first decision and
    follows the reference, not the estimate: every robot of a team slews alike."""

    def __init__(self, rate: float, horizon: int, period: float) -> None:
        self.rate = rate
        self._reach = rate * period * np.arange(horizon + 1)[:, None]
        self.attitude: np.ndarray | None = None

    def reset(self) -> None:
        self.attitude = None

    def apply(self, xd: np.ndarray, vd: np.ndarray, x_o: np.ndarray) -> None:
        """Slew ``xd``'s attitude (the waypoint's, in every row) and cap ``vd``'s angular
        speed, in place; advance the slewed attitude one period."""
        if self.attitude is None:
            self.attitude = np.array(x_o, dtype=float).reshape(-1)[3:6]
        error = wrap_angle(xd[0, 3:] - self.attitude)
        xd[:, 3:] = self.attitude + np.minimum(np.maximum(error, -self._reach), self._reach)
        w = vd[:, 3:]
        speed = np.linalg.norm(w, axis=1)
        over = speed > self.rate
        if over.any():
            w[over] *= (self.rate / speed[over])[:, None]
        self.attitude = xd[1, 3:].copy()


class GoalIntegral:
    """Integral action near the last waypoint (``goal_integral_gain``): within
    ``goal_integral_radius`` of it the object's pose error (position and wrapped Euler
    angles) is integrated, clipped so that ``|k_i I|`` stays within
    ``goal_integral_limit`` / ``goal_integral_angle_limit``, and the horizon's pose
    reference moves by ``-k_i I``: a steady force the model lacks (a current, a
    mismatched buoyancy) cannot leave a steady offset at the goal."""

    def __init__(self, settings: NMPCSettings, waypoints: np.ndarray) -> None:
        self.gain = settings.goal_integral_gain
        self.radius = settings.goal_integral_radius
        self.period = settings.period
        self.integral = np.zeros(6)
        limits = [settings.goal_integral_limit, settings.goal_integral_angle_limit]
        self._clip = np.repeat(limits, 3) / max(self.gain, 1e-12)
        self._wp = np.ascontiguousarray(waypoints, dtype=float)

    def reset(self) -> None:
        self.integral[:] = 0.0

    def shift(self, x_o: np.ndarray, index: int) -> np.ndarray:
        """Update the integral with the pose ``x_o`` while heading to waypoint ``index``
        and return the reference's shift (6,): ``-k_i I`` (zero before the last one)."""
        if self.gain == 0 or index != len(self._wp) - 1:
            return np.zeros(6)
        pose = np.asarray(x_o, dtype=float).reshape(-1)
        att = wrap_angle(pose[3:] - self._wp[index, 3:])
        err = np.concatenate([pose[:3] - self._wp[index, :3], att])
        if np.linalg.norm(err[:3]) < self.radius:
            self.integral[:] = np.clip(self.integral + self.period * err, -self._clip, self._clip)
        return -self.gain * self.integral
