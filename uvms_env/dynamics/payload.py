"""Dynamics of the grasped object (a tube: a bar or a ring), in the inertial frame.

    M_O(x_O) v_O_dot + h_O(x_O, v_O, v_c) = sum_i J_Oi^T lambda_i

with x_O = [p; Theta] (ZYX Euler) and v_O = [p_dot; omega] in the inertial frame, the
object origin at its centroid. The body-frame Newton-Euler equations with added mass
(Kirchhoff), strip-theory drag and net weight are mapped to inertial coordinates:
V = blkdiag(R^T, R^T) v_O and Vdot = blkdiag(R^T, R^T) v_O_dot + [-w x v; 0].

``p_O`` holds what a scenario may perturb (mass, displaced volume, added-mass and drag
scales: the first ``NPO`` entries) and then the object's shape: its rigid inertia per kg
and added mass (6x6 each), the drag per metre of its tube and its strips (``Strips``:
centre, unit axis and length of each, padded with strips of length 0 to the capacity
``strip_capacity``). Every number that tells one object from another is an input of the
functions, none is a constant of their code, so one compiled library serves every object
of a capacity (a ring of any radius and a bar of up to 5.4 m share one; layout:
``parameter_layout``).

Grasp kinematics (paper eq3-eq4): end effector i sits at p_O + R_O l_i with rotation
R_O R_Oi; its inertial twist is J_Oi v_O, J_Oi = [[I, -S(R_O l_i)], [0, I]].

An object is a shape and a size: a ring's radius or a bar's length (0: the parameter
file's bar, ``object.bar.length``). ``object_key`` writes both as one number, the key
the priors and the compiled functions take (``Scenario.object_key``; the datasets store
it as ``object_key``): the ring's radius, 0 for the parameter file's bar, minus
the length for another bar.

May import: numpy, casadi, ``uvms_env.models`` and the sibling ``dynamics`` modules.
"""

from __future__ import annotations

import itertools
import math

import casadi as cs
import numpy as np

from uvms_env.dynamics.hydro import (
    Strips,
    TubeCoefficients,
    current_twist_rate,
    kirchhoff_coriolis,
    strip_drag,
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
NPO = 4  # the physical parameters above; the shape follows them in p_O
# The shape's parts after them (``parameter_layout``): rigid inertia per kg and added mass
# (6x6, column-major), the drag per metre (cross-flow, axial, linear), then the strips.
_SHAPE_SIZES = {"unit_inertia": 36, "added_mass": 36, "drag": 3}
STRIP_SIZE = 7  # one strip: centre (3), unit axis (3), length (object frame)
DEFAULT_RING_RADIUS = 1.6  # m, a ring built without a size
# Strip length of a bar's strip theory: the parameter file's 1.8 m bar in 8 strips; a
# longer bar keeps the strip length (more strips), so its drag is resolved alike.
BAR_STRIP_LENGTH = 0.225  # m
# Two sizes of one shape closer than this are the same object.
SIZE_TOLERANCE = 1e-9


def strip_capacity(strips: int, params: Parameters | None = None) -> int:
    """The strip slots of an object of ``strips`` strips: whole blocks of a ring's strip
    count (``object.ring.segments``), so that every ring and the bars of as many strips or
    fewer (up to 5.4 m) share one capacity, hence one compiled library."""
    block = (params or load_parameters()).object.ring_segments
    return block * max(1, math.ceil(strips / block))


def parameter_layout(capacity: int) -> dict[str, slice]:
    """Where each part of p_O lies for a strip ``capacity``: ``physical`` (the ``NPO``
    entries of ``OBJECT_PARAMETER_LAYOUT``), ``unit_inertia``, ``added_mass``, ``drag``
    and ``strips`` (``STRIP_SIZE`` x capacity, column-major: one strip per column)."""
    sizes = {"physical": NPO, **_SHAPE_SIZES, "strips": STRIP_SIZE * capacity}
    ends = list(itertools.accumulate(sizes.values()))
    return {k: slice(e - n, e) for (k, n), e in zip(sizes.items(), ends, strict=True)}


def parameter_count(capacity: int) -> int:
    """The length of p_O for a strip ``capacity``."""
    return parameter_layout(capacity)["strips"].stop


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
    """Model of the object. ``shape`` is "bar" or "ring"; ``size`` (m) a ring's radius
    (default 1.6) or a bar's length (``bar_length``: None, 0 or the object key's negative
    length all name a bar).

    Its numbers (``nominal_parameters``) and its functions (``dynamics``, ``energy``,
    ``pose_rate``), whose code depends on the strip ``capacity`` only: objects of one
    capacity build the same functions and differ in the parameters they are given."""

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
        self.capacity = strip_capacity(len(self.strips.lengths), prm)
        self.parameter_count = parameter_count(self.capacity)
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
        """The object's functions of (x_O, v_O, v_c, p_O): ``dynamics`` (mass matrix and
        bias in the world frame), ``energy`` and ``pose_rate``; the shape read from p_O."""
        x, v = cs.SX.sym("x_O", 6), cs.SX.sym("v_O", 6)
        v_c, p = cs.SX.sym("v_c", 3), cs.SX.sym("p_O", self.parameter_count)
        part = parameter_layout(self.capacity)
        mass = p[OBJECT_PARAMETER_LAYOUT["mass"]]
        m_rb = mass * cs.reshape(p[part["unit_inertia"]], 6, 6)
        m_a = p[OBJECT_PARAMETER_LAYOUT["added_mass_scale"]] * cs.reshape(
            p[part["added_mass"]], 6, 6
        )
        strips = cs.reshape(p[part["strips"]], STRIP_SIZE, self.capacity)
        rot = rot_zyx(x[3:6])
        rb = cs.diagcat(rot.T, rot.T)
        body = rb @ v
        vc_body = rot.T @ v_c
        v_r = body - cs.vertcat(vc_body, cs.DM.zeros(3))
        m_tot = m_rb + m_a
        frame_rate = cs.vertcat(-cs.cross(body[3:], body[:3]), cs.DM.zeros(3))
        drag = strip_drag(
            v_r,
            [strips[0:3, k] for k in range(self.capacity)],
            [strips[3:6, k] for k in range(self.capacity)],
            [strips[6, k] for k in range(self.capacity)],
            tuple(p[part["drag"]][k] for k in range(3)),
            p[OBJECT_PARAMETER_LAYOUT["drag_scale"]],
        )
        h_body = (
            m_tot @ frame_rate
            - m_a @ current_twist_rate(body[3:], vc_body)
            + kirchhoff_coriolis(m_rb, body)
            + kirchhoff_coriolis(m_a, v_r)
            + drag
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

    @classmethod
    def of_capacity(cls, capacity: int) -> ObjectModel:
        """An object of ``capacity`` strip slots, for the functions of every object of that
        capacity (their code depends on nothing else): the default ring for the first
        block, a bar with as many strips beyond it."""
        ring = cls("ring")
        if ring.capacity == capacity:
            return ring
        bar = cls("bar", capacity * BAR_STRIP_LENGTH)
        if bar.capacity != capacity:
            raise ValueError(f"no object has a strip capacity of {capacity}")
        return bar

    def nominal_parameters(self) -> np.ndarray:
        """p_O of the parameter file: the physical parameters, then the shape, its strips
        padded to the capacity (a padding strip: at the origin, along x, of length 0)."""
        return self._parameters(
            self.nominal_mass, self.nominal_volume, self.unit_inertia, self.added_mass, self.strips
        )

    def carried_parameters(
        self, grasp_offset: np.ndarray, share: float, piece: float = 1.0
    ) -> np.ndarray:
        """p_O of what a robot grasping the object at ``grasp_offset`` (object frame) with
        load share ``share`` in (0, 1] carries whole (load share 1 in its model): ``share``
        of the mass and displaced volume, and of the inertia, added mass and drag a blend,
        ``1 - piece`` of the share of the whole object (the paper's model: its share at
        the centroid) and ``piece`` of its piece: the strips nearest the grasp, taken in
        order of distance until they hold ``share`` of the tube's length (more from the
        inner side where the grasp is near a bar's end). Expressed about the object's
        origin like ``nominal_parameters``. Why a piece: the whole object's share sits at
        the centroid, whose lever arm makes every robot of a long bar push a large moment
        that its teammates push back (docs/results/expert.md)."""
        if not 0.0 < share <= 1.0:
            raise ValueError(f"share must lie in (0, 1], got {share!r}")
        if not 0.0 <= piece <= 1.0:
            raise ValueError(f"piece must lie in [0, 1], got {piece!r}")
        near = np.linalg.norm(self.strips.centers - np.asarray(grasp_offset, float), axis=1)
        order = np.argsort(near, kind="stable")
        target = share * self.length
        before = np.cumsum(self.strips.lengths[order]) - self.strips.lengths[order]
        held = np.zeros(len(near), dtype=bool)
        held[order[before < target - SIZE_TOLERANCE]] = True
        own = Strips(
            self.strips.centers[held],
            self.strips.axes[held],
            self.strips.lengths[held],
            self.strips.radius,
        )
        fill = target / own.total_length  # the last strip is whole: scale to the share
        # every number below is linear in the strips' weights: the blend is exact
        weight = (1.0 - piece) * share + piece * fill * held
        strips = Strips(
            self.strips.centers, self.strips.axes, self.strips.lengths * weight, self.strips.radius
        )
        return self._parameters(
            share * self.nominal_mass,
            share * self.nominal_volume,
            (1.0 - piece) * self.unit_inertia + piece * tube_rigid_inertia(own, 1.0),
            (1.0 - piece) * share * self.added_mass
            + piece * fill * tube_added_mass(own, self.coef),
            strips,
        )

    def _parameters(
        self,
        mass: float,
        volume: float,
        unit_inertia: np.ndarray,
        added_mass: np.ndarray,
        strips: Strips,
    ) -> np.ndarray:
        part = parameter_layout(self.capacity)
        p = np.zeros(self.parameter_count)
        p[OBJECT_PARAMETER_LAYOUT["mass"]] = mass
        p[OBJECT_PARAMETER_LAYOUT["displaced_volume"]] = volume
        p[OBJECT_PARAMETER_LAYOUT["added_mass_scale"]] = 1.0
        p[OBJECT_PARAMETER_LAYOUT["drag_scale"]] = 1.0
        p[part["unit_inertia"]] = unit_inertia.T.reshape(-1)  # column-major
        p[part["added_mass"]] = added_mass.T.reshape(-1)
        c = self.coef
        p[part["drag"]] = [c.drag_cross, c.drag_axial, c.drag_linear]
        rows = np.zeros((self.capacity, STRIP_SIZE))
        rows[:, 3] = 1.0
        count = len(strips.lengths)
        rows[:count, 0:3] = strips.centers
        rows[:count, 3:6] = strips.axes
        rows[:count, 6] = strips.lengths
        p[part["strips"]] = rows.reshape(-1)  # strip k: entries 7k .. 7k + 6
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
