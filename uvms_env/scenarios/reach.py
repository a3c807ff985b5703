"""Is a scenario's ocean current within the team's reach? The team's top speed in still
water, from the model's own damping.

``team_top_speed``: the team translates rigidly at speed V along a horizontal direction
d, every vehicle pushes along d with surge and sway at full saturation, and V solves

    sum_i f_max (|x_i . d| + |y_i . d|) = P(V) / V,

P(V) the power the water takes from the team, from ``UVMSModel.bias`` and
``ObjectModel.dynamics`` so that drag has one source. Nominal model with the scenario's
``damping_scale``; ``mismatch`` is ignored. Reference (the argument and the paper team's
figures): docs/model.md, "Ocean current and mismatch".

May import: numpy, scipy (when called), ``uvms_env.models``, ``uvms_env.dynamics``.
"""

from __future__ import annotations

import weakref

import numpy as np

from uvms_env.dynamics import NQ, ObjectModel
from uvms_env.dynamics.payload import OBJECT_PARAMETER_LAYOUT
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import default_model, scale_damping
from uvms_env.models import load_parameters
from uvms_env.scenarios.config import Scenario

__all__ = ["current_within_reach", "reachable", "team_top_speed"]

_SWEEP = 36  # directions over a half turn (top speed along d and -d is the same)
_V_MAX = 20.0  # m/s, bracket of the root search
_cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _unit(direction) -> np.ndarray:
    d = np.array([direction[0], direction[1], 0.0], dtype=float)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"direction must be a nonzero horizontal vector, got {direction!r}")
    return d / norm


def _heading(psi: float) -> np.ndarray:
    return np.array([np.cos(psi), np.sin(psi), 0.0])


class _Team:
    """The scenario's start configuration and nominal model, evaluated once."""

    def __init__(self, scenario: Scenario) -> None:
        self.uvms = default_model()
        self.p = scale_damping(self.uvms.nominal_parameters(), scenario.damping_scale)
        self.object = ObjectModel(scenario.object_shape, scenario.object_size)
        self.po = self.object.nominal_parameters()
        self.po[OBJECT_PARAMETER_LAYOUT["drag_scale"]] *= scenario.damping_scale
        self.q = np.asarray(scenario.initial_q, dtype=float)
        self.x_o = np.asarray(scenario.object_start, dtype=float)
        self.rot = [np.array(rot_zyx(q[3:6])) for q in self.q]
        self.f_max = load_parameters().limits.vehicle_force

    def thrust(self, d: np.ndarray) -> float:
        return float(sum(self.f_max * (abs(r[:, 0] @ d) + abs(r[:, 1] @ d)) for r in self.rot))

    def drag(self, v: np.ndarray) -> float:
        speed = float(np.linalg.norm(v))
        if speed == 0.0:
            return 0.0
        still = np.zeros(3)
        power = 0.0
        for q, r in zip(self.q, self.rot, strict=True):
            zeta = np.zeros(NQ)
            zeta[:3] = r.T @ v  # body-fixed vehicle twist, arms still
            power += zeta @ np.array(self.uvms.bias(q, zeta, still, self.p)).ravel()
        v_o = np.concatenate([v, np.zeros(3)])
        _, h_o = self.object.dynamics(self.x_o, v_o, still, self.po)
        return float((power + v_o @ np.array(h_o).ravel()) / speed)

    def speed_along(self, d: np.ndarray) -> float:
        from scipy.optimize import brentq  # here: importing scenarios stays light

        thrust = self.thrust(d)
        if self.drag(_V_MAX * d) <= thrust:
            return float("inf")  # no damping (damping_scale = 0) or beyond any real speed
        return float(brentq(lambda v: self.drag(v * d) - thrust, 0.0, _V_MAX, xtol=1e-7))


def team_top_speed(scenario: Scenario, direction=None) -> float:
    """The team's top speed [m/s] in still water (see the module docstring).

    ``direction``: a horizontal vector (world, NED; only x and y count) to push along; None:
    the best direction (the largest speed over all horizontal directions). Cached per
    scenario and direction."""
    key = None if direction is None else tuple(np.round(_unit(direction), 12))
    per_scenario = _cache.setdefault(scenario, {})
    if key not in per_scenario:
        team = _Team(scenario)
        if direction is not None:
            per_scenario[key] = team.speed_along(_unit(direction))
        else:
            angles = np.pi * np.arange(_SWEEP) / _SWEEP
            speeds = [team.speed_along(_heading(a)) for a in angles]
            k = int(np.argmax(speeds))
            best = speeds[k]
            if np.isfinite(best):
                from scipy.optimize import minimize_scalar

                step = np.pi / _SWEEP
                res = minimize_scalar(
                    lambda a: -team.speed_along(_heading(a)),
                    bounds=(angles[k] - step, angles[k] + step),
                    method="bounded",
                    options={"xatol": 1e-4},
                )
                best = max(best, -float(res.fun))
            per_scenario[key] = best
    return per_scenario[key]


def current_within_reach(scenario: Scenario) -> tuple[bool, float, float]:
    """(within reach, current speed, top speed): the scenario's current preset's mean
    speed [m/s] against the team's top speed along its best direction. False means no
    controller can hold the team against that current (a failure there is not the
    controller's)."""
    current = load_parameters().currents[scenario.current].mean
    top = team_top_speed(scenario)
    return bool(current < top), float(current), float(top)


def reachable(scenario: Scenario) -> bool:
    """``current_within_reach(scenario)[0]`` at a fraction of its cost (an evaluator asks
    once per episode): the drag grows with the speed, so the top speed along a direction
    d exceeds the current's speed c exactly where the drag at c d is below the thrust
    along d; the sweep's directions are tried first (one drag each, no root search), and
    only where none has it does the whole search decide."""
    if scenario.current == "none":
        return True
    current = load_parameters().currents[scenario.current].mean
    team = _Team(scenario)
    for a in np.pi * np.arange(_SWEEP) / _SWEEP:
        d = _heading(a)
        if team.drag(current * d) < team.thrust(d):
            return True
    return current_within_reach(scenario)[0]
