"""The task's constraints, as symbolic expressions with one sign convention: g <= 0 holds.

Each robot reports one value per kind (``CONSTRAINTS``); all are evaluated on the true
state after the step (the physical system is what must stay safe, not an estimate):

================  ========================================================================
kind              g (<= 0 means satisfied)
================  ========================================================================
input             max_k |a_k| - 1: a requested normalized input beyond the saturation
joint_limit       max_m |q_m| - ``joint_position``
joint_speed       max_m |qdot_m| - ``joint_speed``
vehicle_speed     max(max |u, v, w| / ``vehicle_linear_speed``,
                  max |p, q, r| / ``vehicle_angular_speed``) - 1: the faster axis's
                  speed beyond its limit, as a fraction of that limit (two units in one
                  kind: the fraction is what they share)
manipulability    eps - det(Jbar Jbar^T), eps = ``MANIPULABILITY_EPS``, Jbar the 8 actuated
                  columns of the end-effector Jacobian (about 4.2 at the paper's start)
representation    max(|theta_O|, |theta_i|) - (pi/2 - ``REPRESENTATION_MARGIN``): object and
                  vehicle pitch away from the ZYX Euler singularity
collision         -clearance: the smallest signed distance from the robot's bodies and from
                  the object to any obstacle (m; clearances beyond 100 m read 100 m)
workspace         the largest distance by which the robot's bodies or the object reach
                  outside the workspace ball (m)
================  ========================================================================

Graded safety (``constraint_scales``, ``SAFETY_CONSTRAINTS``): each kind's value divided
by its scale, ``max(0, g) / scale``, is its excess as a fraction of the limit (input 1,
joint_limit ``joint_position``, joint_speed ``joint_speed``, vehicle_speed 1 (already a
fraction), manipulability ``MANIPULABILITY_EPS``, representation pi/2 -
``REPRESENTATION_MARGIN``, collision and workspace the vehicle's bounding radius: a
penetration or an excursion as a fraction of the robot's size). ``CLEAN_TOLERANCE`` is the
band of clean success with a tolerance. ``input`` is reported per kind but is not a safety
kind: the requested input is clipped before the simulator, every applied input is within
the saturation, and the ladder's policies (the expert, the loaders, SB3, the random
policy) clip before they act, so a violation is a caller's out-of-space request, not the
robot leaving its envelope. The totals (violation periods, clean success, the graded
totals, the reward's violation term and each robot's ``cost``) count
``SAFETY_CONSTRAINTS`` only (and any extra constraints).

Bodies: the vehicle is a sphere of radius ``vehicle.bounding_radius`` at its origin, the
arm links are capsules of radius ``arm.tube_radius`` between consecutive columns 1..5 of
``body_points`` (joint 1, ..., joint 4, end effector; the vehicle-to-joint-1 stretch lies
inside the vehicle sphere), the object is capsules of its tube radius along its segments.
Vertical cylinders are infinite in z. The object is shared, so its collision and
workspace terms enter every robot's value.

One source per limit: the physical limits (the ``joint_position``, ... above) are the
model's, ``parameters.toml`` (``[limits]``, read through ``params.limits``); the task's
own two, ``MANIPULABILITY_EPS`` and ``REPRESENTATION_MARGIN``, are defined here and
nowhere else. The expert's bounds (``nmpc_expert.settings``) are derived from both,
never retyped. May import: numpy, casadi and ``uvms_env.models``.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from uvms_env.models import Parameters

CONSTRAINTS = (
    "input",
    "joint_limit",
    "joint_speed",
    "vehicle_speed",
    "manipulability",
    "representation",
    "collision",
    "workspace",
)
#: The kinds the safety totals count: every kind but ``input`` (module docstring).
SAFETY_CONSTRAINTS = tuple(c for c in CONSTRAINTS if c != "input")
#: Clean success with a tolerance: no kind beyond this fraction of its scale.
CLEAN_TOLERANCE = 0.05
# Always end the episode, whatever the constraint mode: the bodies have hit something.
HARD_CONSTRAINTS = ("collision",)

# The paper leaves eps open. det(Jbar Jbar^T) is ~4.2 at the paper scenario's start and
# falls towards 0 only as the arm stretches out or folds near a singularity; 0.5 leaves the
# arm room to work and never binds in normal transport. Read at call time by
# ``robot_constraints`` and by the expert's settings (``nmpc_expert.settings``).
MANIPULABILITY_EPS = 0.5
# Margin from the Euler singularity |theta| = pi/2 where T(Theta) blows up (rad); the
# object's and the vehicles' pitch bound, for the environment and the expert alike.
REPRESENTATION_MARGIN = 0.2
# Clearances beyond this read as this (m): no obstacle nearby, or none at all.
MAX_CLEARANCE = 100.0
# Far-away stand-ins that pad the obstacle lists to a few fixed lengths, so a few compiled
# functions serve every scenario with the same number of robots.
PAD_CYLINDER = (1e6, 1e6, 0.0)
PAD_SPHERE = (1e6, 1e6, 1e6, 0.0)


def constraint_scales(params: Parameters) -> tuple[float, ...]:
    """The scale of each kind's value (order of ``CONSTRAINTS``): one unit of
    ``max(0, g) / scale`` is a violation by the whole limit (module docstring)."""
    lim = params.limits
    length = params.vehicle.bounding_radius
    scale = {
        "input": 1.0,
        "joint_limit": lim.joint_position,
        "joint_speed": lim.joint_speed,
        "vehicle_speed": 1.0,
        "manipulability": MANIPULABILITY_EPS,
        "representation": np.pi / 2 - REPRESENTATION_MARGIN,
        "collision": length,
        "workspace": length,
    }
    return tuple(float(scale[c]) for c in CONSTRAINTS)


def segment_point_distance(a: cs.SX, b: cs.SX, c: cs.SX) -> cs.SX:
    """Distance from point c to the segment [a, b] (any dimension; a == b allowed)."""
    d = b - a
    dd = cs.dot(d, d)
    t = cs.fmin(cs.fmax(cs.dot(c - a, d) / cs.fmax(dd, 1e-12), 0.0), 1.0)
    e = c - (a + t * d)
    return cs.sqrt(cs.dot(e, e) + 1e-18)


def capsule_clearance(a: cs.SX, b: cs.SX, radius: float, cylinders: cs.SX, spheres: cs.SX) -> cs.SX:
    """Smallest signed distance from the capsule (a, b, radius) to the obstacles.

    ``cylinders`` is 3 x C (x, y, radius), ``spheres`` 4 x P (centre, radius)."""
    out = cs.SX(np.inf)
    for k in range(cylinders.shape[1]):
        c = cylinders[:, k]
        out = cs.fmin(out, segment_point_distance(a[:2], b[:2], c[:2]) - c[2] - radius)
    for k in range(spheres.shape[1]):
        s = spheres[:, k]
        out = cs.fmin(out, segment_point_distance(a, b, s[:3]) - s[3] - radius)
    return out


def ball_excess(points: list[tuple[cs.SX, float]], workspace: cs.SX) -> cs.SX:
    """Largest distance by which balls (centre, radius) reach outside the workspace ball
    (workspace = [centre; radius]); <= 0 when all are inside."""
    out = cs.SX(-np.inf)
    for p, r in points:
        e = p - workspace[:3]
        out = cs.fmax(out, cs.sqrt(cs.dot(e, e) + 1e-18) + r - workspace[3])
    return out


def robot_constraints(
    params: Parameters,
    action: cs.SX,
    q: cs.SX,
    zeta: cs.SX,
    object_pitch: cs.SX,
    manipulability: cs.SX,
    clearance: cs.SX,
    workspace_excess: cs.SX,
) -> cs.SX:
    """The constraint vector of one robot, ordered as ``CONSTRAINTS``.

    ``clearance`` and ``workspace_excess`` already include the object's terms."""
    lim = params.limits
    amax = cs.mmax(cs.fabs(action))
    g = [
        amax - 1.0,
        cs.mmax(cs.fabs(q[6:])) - lim.joint_position,
        cs.mmax(cs.fabs(zeta[6:])) - lim.joint_speed,
        cs.fmax(
            cs.mmax(cs.fabs(zeta[:3])) / lim.vehicle_linear_speed,
            cs.mmax(cs.fabs(zeta[3:6])) / lim.vehicle_angular_speed,
        )
        - 1.0,
        MANIPULABILITY_EPS - manipulability,
        cs.fmax(cs.fabs(object_pitch), cs.fabs(q[4])) - (np.pi / 2 - REPRESENTATION_MARGIN),
        -cs.fmin(clearance, MAX_CLEARANCE),
        workspace_excess,
    ]
    return cs.vertcat(*g)
