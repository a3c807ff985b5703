"""Dynamics of the grasped object (a tube: a bar or a ring), in the inertial frame.

    M_O(x_O) v_O_dot + h_O(x_O, v_O, v_c) = sum_i J_Oi^T lambda_i

with x_O = [p; Theta] (ZYX Euler) and v_O = [p_dot; omega] in the inertial frame, the
object origin at its centroid. The body-frame Newton-Euler equations with added mass
(Kirchhoff), strip-theory drag and net weight are mapped to inertial coordinates:
V = blkdiag(R^T, R^T) v_O and Vdot = blkdiag(R^T, R^T) v_O_dot + [-w x v; 0].

``p_O`` holds what a scenario may perturb: mass, displaced volume, added-mass and drag
scales. Grasp kinematics (paper eq3-eq4): end effector i sits at p_O + R_O l_i with
rotation R_O R_Oi; its inertial twist is J_Oi v_O, J_Oi = [[I, -S(R_O l_i)], [0, I]].

An object is a shape and a size: a ring's radius or a bar's length (0: the parameter
file's bar, ``object.bar.length``). ``object_key`` writes both as one number, the name
the compiled functions, the priors and the datasets use (``object_ring_radius``): the
ring's radius, 0 for the parameter file's bar, minus the length for another bar.

May import: numpy, casadi, ``uvms_env.models`` and the sibling ``dynamics`` modules.
"""

from __future__ import annotations

import math

import casadi as cs
import numpy as np

from uvms_env.dynamics.hydro import (
    Strips,
    TubeCoefficients,
    current_twist_rate,
    kirchhoff_coriolis,
    strip_damping,
    tube_added_mass,
    tube_rigid_inertia,
)
from uvms_env.dynamics.spatial import euler_rate_matrix, rot_zyx, skew
from uvms_env.models import Parameters, load_parameters

OBJECT_PARAMETER_LAYOUT: dict[str, int] = {
    "mass": 0,
    "displaced_volume": 1,
    "added_mass_scale": 2,
    "drag_scale": 3,
}
NPO = 4
DEFAULT_RING_RADIUS = 1.6  # m, a ring built without a size
# Strip length of a bar's strip theory: the parameter file's 1.8 m bar in 8 strips; a
# longer bar keeps the strip length (more strips), so its drag is resolved alike.
BAR_STRIP_LENGTH = 0.225  # m
# Two sizes of one shape closer than this are the same object.
SIZE_TOLERANCE = 1e-9


def bar_length(size: float | None, params: Parameters | None = None) -> float:
    """A bar's length from its size: ``|size|`` (the object key writes a bar's length
    negative), the parameter file's ``object.bar.length`` for 0 or None."""
    if size is None or abs(float(size)) < SIZE_TOLERANCE:
        return (params or load_parameters()).object.bar_length
    return abs(float(size))


def object_key(shape: str, size: float | None, params: Parameters | None = None) -> float:
    """The object as one number: a ring's radius; 0 for the parameter file's bar, minus
    the length for another bar. Equal objects get equal keys (a bar of the file's length
    is 0, whether its size says 0 or the length)."""
    if shape == "ring":
        return float(size) if size is not None else DEFAULT_RING_RADIUS
    if shape != "bar":
        raise ValueError(f"unknown object shape {shape!r}: expected 'bar' or 'ring'")
    length = bar_length(size, params)
    default = (params or load_parameters()).object.bar_length
    return 0.0 if abs(length - default) < SIZE_TOLERANCE else -length


def object_size(shape: str, size: float | None, params: Parameters | None = None) -> float:
    """The canonical size of an object (what a scenario stores): a ring's radius; a bar's
    length, 0 for the parameter file's bar, so that its compiled functions keep one name."""
    return abs(object_key(shape, size, params))


def object_tag(key: float) -> str:
    """An object key inside compiled functions' names: ``1p6000`` for a ring of 1.6 m,
    ``0p0000`` for the parameter file's bar, ``m5p0000`` for a 5 m bar."""
    return f"{float(key):.4f}".replace(".", "p").replace("-", "m")


def bar_segments(length: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A straight bar along the object's y axis, centred at the origin."""
    return [(np.array([0.0, -length / 2, 0.0]), np.array([0.0, length / 2, 0.0]))]


def ring_segments(radius: float, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """A horizontal hoop (polygon of n sides) in the object's x-y plane."""
    ang = 2 * np.pi * np.arange(n + 1) / n
    pts = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n + 1)], axis=1)
    return [(pts[k], pts[k + 1]) for k in range(n)]


class ObjectModel:
    """Symbolic model of the object. ``shape`` is "bar" or "ring"; ``size`` (m) a ring's
    radius (default 1.6) or a bar's length (``bar_length``: None, 0 or the object key's
    negative length all name a bar)."""

    def __init__(
        self, shape: str = "bar", size: float | None = None, params: Parameters | None = None
    ) -> None:
        prm = params or load_parameters()
        obj = prm.object
        if shape == "bar":
            length = bar_length(size, prm)
            segments = bar_segments(length)
            per = max(1, math.ceil(round(length / BAR_STRIP_LENGTH, 6)))
        elif shape == "ring":
            radius = DEFAULT_RING_RADIUS if size is None else float(size)
            if not (math.isfinite(radius) and radius > 0):
                raise ValueError(f"a ring's radius must be a finite float > 0, got {size!r}")
            segments, per = ring_segments(radius, obj.ring_segments), 1
        else:
            raise ValueError(f"unknown object shape {shape!r}: expected 'bar' or 'ring'")
        self.shape = shape
        self.key = object_key(shape, size, prm)
        self.segments = segments
        self.strips = Strips.along(segments, obj.tube_radius, per)
        self.length = self.strips.total_length
        self.radius = obj.tube_radius
        rho, g = prm.water_density, prm.gravity
        volume = np.pi * obj.tube_radius**2 * self.length
        self.nominal_mass = rho * volume + obj.net_weight / g
        self.nominal_volume = volume
        coef = TubeCoefficients.for_tube(
            obj.tube_radius,
            self.nominal_mass / self.length,
            rho,
            obj.drag_coefficient,
            obj.axial_added_mass_fraction,
            obj.axial_drag_coefficient,
            obj.linear_drag_per_length,
        )
        self.coef = coef
        self.unit_inertia = tube_rigid_inertia(self.strips, 1.0)  # per kg
        self.added_mass = tube_added_mass(self.strips, coef)
        self.bounding_radius = (
            float(
                max(
                    np.linalg.norm(
                        np.concatenate([s for s, _ in segments] + [e for _, e in segments]).reshape(
                            -1, 3
                        ),
                        axis=1,
                    )
                )
            )
            + obj.tube_radius
        )
        self._build_functions(prm.water_density, prm.gravity)

    def _build_functions(self, rho: float, g: float) -> None:
        """The object's compiled-graph functions: ``dynamics`` (mass matrix and bias in
        the world frame), ``energy`` and ``pose_rate``."""
        coef = self.coef
        x, v = cs.SX.sym("x_O", 6), cs.SX.sym("v_O", 6)
        v_c, p = cs.SX.sym("v_c", 3), cs.SX.sym("p_O", NPO)
        mass = p[OBJECT_PARAMETER_LAYOUT["mass"]]
        m_rb = mass * cs.DM(self.unit_inertia)
        m_a = p[OBJECT_PARAMETER_LAYOUT["added_mass_scale"]] * cs.DM(self.added_mass)
        rot = rot_zyx(x[3:6])
        rb = cs.diagcat(rot.T, rot.T)
        body = rb @ v
        vc_body = rot.T @ v_c
        v_r = body - cs.vertcat(vc_body, cs.DM.zeros(3))
        m_tot = m_rb + m_a
        frame_rate = cs.vertcat(-cs.cross(body[3:], body[:3]), cs.DM.zeros(3))
        h_body = (
            m_tot @ frame_rate
            - m_a @ current_twist_rate(body[3:], vc_body)
            + kirchhoff_coriolis(m_rb, body)
            + kirchhoff_coriolis(m_a, v_r)
            + strip_damping(v_r, self.strips, coef, p[OBJECT_PARAMETER_LAYOUT["drag_scale"]])
        )
        net_weight = (mass - rho * p[OBJECT_PARAMETER_LAYOUT["displaced_volume"]]) * g
        g_w = cs.vertcat(0, 0, -net_weight, 0, 0, 0)
        m_w = rb.T @ m_tot @ rb
        self.dynamics = cs.Function(
            "object_dynamics", [x, v, v_c, p], [0.5 * (m_w + m_w.T), rb.T @ h_body + g_w]
        )
        self.energy = cs.Function(
            "object_energy", [x, v, p], [0.5 * cs.dot(body, m_tot @ body) - net_weight * x[2]]
        )
        self.pose_rate = cs.Function(
            "object_pose_rate",
            [x, v],
            [cs.vertcat(v[:3], euler_rate_matrix(x[3:6]) @ rot.T @ v[3:])],
        )

    @classmethod
    def from_key(cls, key: float) -> ObjectModel:
        """The object named by ``object_key``'s number."""
        return cls("ring", key) if key > 0 else cls("bar", key)

    def nominal_parameters(self) -> np.ndarray:
        p = np.zeros(NPO)
        p[OBJECT_PARAMETER_LAYOUT["mass"]] = self.nominal_mass
        p[OBJECT_PARAMETER_LAYOUT["displaced_volume"]] = self.nominal_volume
        p[OBJECT_PARAMETER_LAYOUT["added_mass_scale"]] = 1.0
        p[OBJECT_PARAMETER_LAYOUT["drag_scale"]] = 1.0
        return p


def grasp_jacobian(rot_o: cs.SX | cs.MX, offset: cs.SX | cs.MX | np.ndarray) -> cs.SX | cs.MX:
    """J_Oi = [[I, -S(R_O l_i)], [0, I]]: object twist -> grasp-point twist (inertial)."""
    arm = rot_o @ offset
    eye = cs.DM.eye(3)
    return cs.vertcat(cs.horzcat(eye, -skew(arm)), cs.horzcat(cs.DM.zeros(3, 3), eye))


def grasp_jdot_v(rot_o: cs.SX | cs.MX, offset, v_o: cs.SX | cs.MX) -> cs.SX | cs.MX:
    """Jdot_Oi v_O = [w x (w x R_O l_i); 0]."""
    w = v_o[3:]
    return cs.vertcat(cs.cross(w, cs.cross(w, rot_o @ offset)), 0 * w)
