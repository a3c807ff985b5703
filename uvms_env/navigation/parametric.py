r"""The navigator's twist with the scene as inputs: one branch-free CasADi function for
every geometry, so that environments of different scenes share one compiled (batched)
call.

:meth:`WaypointNavigator.casadi_function` bakes the goal, the workspace, the obstacles,
the team radius and the gains in as constants and selects with ``if_else``; this module
builds the same formulas (:meth:`NavigationField.casadi_velocity` and the attitude law
``field._attitude_rate_ca``) with all of them as inputs:

=============  ============  ==========================================================
input          shape         contents
=============  ============  ==========================================================
``x``          (6, 1)        object pose estimate ``[p; phi, theta, psi]``
``goal``       (6, 1)        waypoint ``[p_d; Theta_d]``
``workspace``  (4, 1)        ``[c_ws; r_ws - R]`` (centre, radius deflated by the team)
``cylinders``  (n_cyl, 4)    rows ``[x, y, r + R, present]``
``spheres``    (n_sph, 5)    rows ``[cx, cy, cz, r + R, present]``
``gains``      (5, 1)        ``[k, K_NF, v_max, K_att, w_max]``
=============  ============  ==========================================================

output ``twist_d`` (6, 1) = ``[v_d; Euler-angle rates]``, as ``nav_twist``. Matrix inputs
are column-major in CasADi's nonzeros (all x, then all y, ...): ``a.ravel(order="F")``.
:func:`twist_parameters` packs a navigator's waypoint into these arrays.

Padding and branch-free code: docs/batched.md, "One kernel for every geometry" (a row
with ``present == 0`` is the neutral factor ``beta = 1``; selections are ``field._select``).

Dependencies: this package may import numpy and casadi only.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from .field import NavigationField, _attitude_rate_ca, scene_velocity
from .waypoints import WaypointNavigator

parametric_velocity = scene_velocity  # the name this module exports

__all__ = [
    "NAV_PARAMETERS",
    "N_CYLINDERS",
    "N_SPHERES",
    "field_parameters",
    "parameter_row",
    "parametric_twist_function",
    "parametric_velocity",
    "twist_parameters",
]

#: Obstacle slots of the shared function: the random family draws at most five
#: obstacles (cylinders or spheres), the paper scenario has three cylinders.
N_CYLINDERS = 5
N_SPHERES = 5
#: Entries of one waypoint's parameters as one row (:func:`parameter_row`): the inputs
#: after ``x``, matrices column-major: goal 6, workspace 4, cylinders 4 x 5, spheres
#: 5 x 5, gains 5.
NAV_PARAMETERS = 6 + 4 + 4 * N_CYLINDERS + 5 * N_SPHERES + 5

FloatArray = NDArray[np.float64]


def parametric_twist_function(n_cyl: int = N_CYLINDERS, n_sph: int = N_SPHERES) -> ca.Function:
    """CasADi function ``nav_twist_param`` (SX, branch-free): ``(x, goal, workspace,
    cylinders, spheres, gains) -> twist_d`` (see the module doc for the layout).

    Equal to ``WaypointNavigator.casadi_function(i)`` of any scene with at most ``n_cyl``
    cylinders and ``n_sph`` spheres, given :func:`twist_parameters` of that waypoint.
    """
    if n_cyl < 0 or n_sph < 0:
        raise ValueError(f"obstacle counts must be >= 0, got {n_cyl}, {n_sph}")
    x = ca.SX.sym("x", 6, 1)
    goal = ca.SX.sym("goal", 6, 1)
    workspace = ca.SX.sym("workspace", 4, 1)
    cylinders = ca.SX.sym("cylinders", n_cyl, 4)
    spheres = ca.SX.sym("spheres", n_sph, 5)
    gains = ca.SX.sym("gains", 5, 1)
    v = scene_velocity(
        x[0:3], goal[0:3], workspace, cylinders, spheres, gains[0], gains[1], gains[2]
    )
    w = _attitude_rate_ca(x[3:6], goal[3:6], gains[3], gains[4])
    return ca.Function(
        "nav_twist_param",
        [x, goal, workspace, cylinders, spheres, gains],
        [ca.vertcat(v, w)],
        ["x", "goal", "workspace", "cylinders", "spheres", "gains"],
        ["twist_d"],
    )


def field_parameters(
    field: NavigationField, n_cyl: int = N_CYLINDERS, n_sph: int = N_SPHERES
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``workspace`` (4,), ``cylinders`` (n_cyl, 4) and ``spheres`` (n_sph, 5) of a field,
    obstacles inflated and the workspace deflated by its team radius, zero padded
    (ValueError if the field has more cylinders or spheres than slots)."""
    cyl_xy, cyl_r = field._cyl_xy, field._cyl_r
    sph_c, sph_r = field._sph_c, field._sph_r
    if cyl_r.size > n_cyl or sph_r.size > n_sph:
        raise ValueError(
            f"the scene has {cyl_r.size} cylinders and {sph_r.size} spheres; the function "
            f"has slots for {n_cyl} and {n_sph}"
        )
    workspace = np.append(field._ws_center, field._ws_radius)
    cylinders = np.zeros((n_cyl, 4))
    cylinders[: cyl_r.size] = np.c_[cyl_xy, cyl_r, np.ones(cyl_r.size)]
    spheres = np.zeros((n_sph, 5))
    spheres[: sph_r.size] = np.c_[sph_c, sph_r, np.ones(sph_r.size)]
    return workspace, cylinders, spheres


def twist_parameters(
    navigator: WaypointNavigator,
    index: int,
    n_cyl: int = N_CYLINDERS,
    n_sph: int = N_SPHERES,
) -> list[FloatArray]:
    """The inputs of :func:`parametric_twist_function` after ``x`` for waypoint ``index``
    of ``navigator``: ``[goal (6,), workspace (4,), cylinders (n_cyl, 4), spheres
    (n_sph, 5), gains (5,)]``; flatten matrices with ``order="F"`` for a (nnz, K) batch.
    """
    if not 0 <= index < len(navigator.sequencer):
        raise ValueError(f"waypoint index {index} out of range 0..{len(navigator.sequencer) - 1}")
    field = navigator.fields[index]
    workspace, cylinders, spheres = field_parameters(field, n_cyl, n_sph)
    goal = navigator.sequencer.waypoints[index].copy()
    gains = np.array(
        [field.k, field.gain, field.max_speed, navigator.att_gain, navigator.max_att_rate]
    )
    return [goal, workspace, cylinders, spheres, gains]


def parameter_row(navigator: WaypointNavigator, index: int) -> FloatArray:
    """(NAV_PARAMETERS,): :func:`twist_parameters` of waypoint ``index`` with the default
    slots, as one row (matrices column-major), the layout a table of waypoints holds."""
    parts = twist_parameters(navigator, index)
    return np.concatenate([np.ravel(p, order="F") for p in parts])


def twist_of_row(x: ca.SX, row: ca.SX) -> ca.SX:
    """The twist (6, 1) at pose ``x`` (6, 1) towards the waypoint whose
    :func:`parameter_row` is ``row`` (NAV_PARAMETERS, 1): the shared function's expression,
    for a larger SX graph (the team kernel's)."""
    fn = parametric_twist_function()
    parts, start = [], 0
    for k in range(1, fn.n_in()):
        rows, cols = fn.size_in(k)
        parts.append(ca.reshape(row[start : start + rows * cols], rows, cols))
        start += rows * cols
    return fn(x, *parts)
