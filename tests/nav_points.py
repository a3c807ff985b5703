"""The navigation fields in NumPy for the tests: ``phi`` and its gradients and the velocity
reference in batches (the package builds the velocity symbolically and only needs the
descent direction and the clearance in NumPy); ``PointField`` reads one row of them, and
``twist`` (with ``attitude_rate``) is a waypoint navigator's reference at one pose. The
formulas and conventions: docs/model.md, "Navigation function"."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uvms_env.navigation import NavigationField, WaypointNavigator, wrap_angle
from uvms_env.navigation.field import EPS, _as_points


def attitude_rate(
    attitude: ArrayLike, attitude_goal: ArrayLike, gain: float = 0.2, max_rate: float = 0.05
) -> np.ndarray:
    """The attitude law in NumPy: ZYX Euler-angle rates [rad/s]
    ``clip(-gain * wrap(attitude - attitude_goal), -max_rate, max_rate)``, elementwise."""
    theta = np.asarray(attitude, dtype=float)
    theta_d = np.asarray(attitude_goal, dtype=float)
    return np.clip(-gain * wrap_angle(theta - theta_d), -max_rate, max_rate)


def _sigmoid(z: np.ndarray) -> np.ndarray:
    # exp of a non-positive argument only, so neither branch overflows.
    ez = np.exp(-np.abs(z))
    return np.where(z >= 0.0, 1.0 / (1.0 + ez), ez / (1.0 + ez))


def _log_parts(field: NavigationField, gamma: np.ndarray, betas: np.ndarray):
    """``z = log beta - k log gamma`` and ``log(gamma^k + beta)`` (free points assumed)."""
    with np.errstate(divide="ignore"):
        log_gamma = np.log(gamma)
    log_beta = np.sum(np.log(np.where(np.all(betas > 0.0, axis=1)[:, None], betas, 1.0)), axis=1)
    k_log_gamma = field.k * log_gamma
    return log_beta - k_log_gamma, np.logaddexp(k_log_gamma, log_beta)


def log_phi_batch(field: NavigationField, points: ArrayLike) -> np.ndarray:
    """``log phi`` at each row of ``points`` (M, 3); 0 outside, -inf at the goal."""
    _, gamma, betas, _, _, free = field._terms(_as_points("points", points))
    z, _ = _log_parts(field, gamma, betas)
    # -(1/k) softplus(z) equals log gamma - (1/k) logaddexp(k log gamma, log beta) but
    # is <= 0 by construction (no phi > 1 from rounding) and -inf exactly at the goal.
    return np.where(free, -np.logaddexp(0.0, z) / field.k, 0.0)


def phi_batch(field: NavigationField, points: ArrayLike) -> np.ndarray:
    """``phi`` at each row of ``points`` (M, 3), in ``[0, 1]``."""
    return np.exp(log_phi_batch(field, points))


def grad_log_phi_batch(field: NavigationField, points: ArrayLike) -> np.ndarray:
    """Gradient of ``log phi`` (M, 3): zero at the goal, the negated unit recovery
    direction outside the free space."""
    e, gamma, betas, grads, s, free = field._terms(_as_points("points", points))
    z, _ = _log_parts(field, gamma, betas)
    at_goal = gamma == 0.0
    safe_gamma = np.where(at_goal, 1.0, gamma)
    g = _sigmoid(z)[:, None] * (2.0 * e / safe_gamma[:, None] - s / field.k)
    g = np.where(at_goal[:, None], 0.0, g)
    return np.where(free[:, None], g, -field._recovery(betas, grads))


def grad_phi_batch(field: NavigationField, points: ArrayLike) -> np.ndarray:
    """Gradient of ``phi`` (M, 3); 0 outside the free space."""
    e, gamma, betas, _, s, free = field._terms(_as_points("points", points))
    z, log_den = _log_parts(field, gamma, betas)
    scale = np.exp(-log_den / field.k) * _sigmoid(z)
    g = scale[:, None] * (2.0 * e - gamma[:, None] * s / field.k)
    return np.where(free[:, None], g, 0.0)


def desired_velocity_batch(field: NavigationField, points: ArrayLike) -> np.ndarray:
    """The velocity reference (M, 3), the formula of ``scene_velocity`` in NumPy."""
    e, gamma, betas, grads, s, free = field._terms(_as_points("points", points))
    n = -(e - gamma[:, None] * s / (2.0 * field.k))
    speed = np.minimum(field.max_speed, field.gain * np.sqrt(gamma + EPS**2))
    v = n * (speed / np.sqrt(np.sum(n * n, axis=1) + EPS**2))[:, None]
    return np.where(free[:, None], v, field.max_speed * field._recovery(betas, grads))


def _row(p: ArrayLike) -> np.ndarray:
    return np.asarray(p, dtype=float).reshape(1, 3)


class PointField:
    """The batch functions above at a single point ``p`` (3,); anything else is the
    field's own attribute."""

    def __init__(self, field: NavigationField) -> None:
        self.field = field

    def __getattr__(self, name: str) -> Any:
        return getattr(self.field, name)

    def log_phi(self, p: ArrayLike) -> float:
        return float(log_phi_batch(self.field, _row(p))[0])

    def phi(self, p: ArrayLike) -> float:
        return math.exp(self.log_phi(p))

    def grad_log_phi(self, p: ArrayLike) -> np.ndarray:
        return grad_log_phi_batch(self.field, _row(p))[0]

    def grad_phi(self, p: ArrayLike) -> np.ndarray:
        return grad_phi_batch(self.field, _row(p))[0]

    def desired_velocity(self, p: ArrayLike) -> np.ndarray:
        return desired_velocity_batch(self.field, _row(p))[0]

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
