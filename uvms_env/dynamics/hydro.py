"""Hydrodynamics of rigid bodies: added mass (Kirchhoff), damping, strip theory for tubes.

Every body (vehicle, arm link, object) is handled the same way in its own body frame,
with its body twist V = [v; w] and the twist relative to the water V_r = V - [R^T v_c; 0]
(v_c: current in the inertial frame, constant over a control period):

    wrench = -(M_A (Vdot - Vdot_c) + C_A(V_r) V_r + D(V_r) V_r),

with C_A from Kirchhoff's equations (Fossen 2011, Thm 6.2: power-free, V.C_A(V)V = 0)
and Vdot_c = [-w x R^T v_c; 0]. The tube model (arm links, the object) integrates
strip theory along the tube: cross-flow added mass rho*pi*r^2 per metre, quadratic
cross-flow and axial drag, a small linear drag. We hand-write this because no
maintained Python library offers Fossen-type hydrodynamics in CasADi.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

from uvms_env.dynamics.spatial import Sym

# |x| is smoothed as sqrt(x^2 + EPS^2) so derivatives stay finite at rest (the NMPC
# differentiates these terms); the error is below 1e-6 m/s.
_EPS = 1e-6


@dataclass(frozen=True)
class Strips:
    """A tube cut into strips: centres (S,3), unit axes (S,3), lengths (S,); body frame."""

    centers: np.ndarray
    axes: np.ndarray
    lengths: np.ndarray
    radius: float

    @staticmethod
    def along(
        segments: list[tuple[np.ndarray, np.ndarray]], radius: float, per_segment: int
    ) -> Strips:
        """Cut each straight segment (start, end) into ``per_segment`` equal strips."""
        c, u, ell = [], [], []
        for start, end in segments:
            start, end = np.asarray(start, float), np.asarray(end, float)
            length = float(np.linalg.norm(end - start))
            if length == 0:
                continue
            for k in range(per_segment):
                c.append(start + (end - start) * (k + 0.5) / per_segment)
                u.append((end - start) / length)
                ell.append(length / per_segment)
        return Strips(np.array(c), np.array(u), np.array(ell), radius)

    @property
    def total_length(self) -> float:
        return float(self.lengths.sum())


@dataclass(frozen=True)
class TubeCoefficients:
    """Per-metre hydrodynamic coefficients of a tube (strip theory)."""

    added_mass_cross: float  # kg/m, rho*pi*r^2
    added_mass_axial: float  # kg/m
    drag_cross: float  # N s^2/m^3, 0.5*rho*Cd*2r
    drag_axial: float  # N s^2/m^3, 0.5*rho*Cd_ax*2*pi*r
    drag_linear: float  # N s/m^2

    @staticmethod
    def for_tube(
        radius: float,
        mass_per_length: float,
        rho: float,
        cd: float,
        axial_added_fraction: float,
        cd_axial: float,
        linear: float,
    ) -> TubeCoefficients:
        return TubeCoefficients(
            added_mass_cross=rho * np.pi * radius**2,
            added_mass_axial=axial_added_fraction * mass_per_length,
            drag_cross=0.5 * rho * cd * 2 * radius,
            drag_axial=0.5 * rho * cd_axial * 2 * np.pi * radius,
            drag_linear=linear,
        )


def spatial_inertia_of_points(masses3: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """6x6 inertia about the body origin of point 'bodies' with 3x3 translational masses."""
    out = np.zeros((6, 6))
    for a, r in zip(masses3, points, strict=True):
        s = _skew_np(r)
        out[:3, :3] += a
        out[:3, 3:] += -a @ s
        out[3:, :3] += s @ a
        out[3:, 3:] += -s @ a @ s
    return out


def _skew_np(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def tube_added_mass(strips: Strips, coef: TubeCoefficients) -> np.ndarray:
    """6x6 added mass about the body origin, summed over strips (plus each strip's own rotation)."""
    masses, out_rot = [], np.zeros((6, 6))
    for u, ell in zip(strips.axes, strips.lengths, strict=True):
        uu = np.outer(u, u)
        masses.append(ell * (coef.added_mass_cross * (np.eye(3) - uu) + coef.added_mass_axial * uu))
        out_rot[3:, 3:] += coef.added_mass_cross * ell**3 / 12 * (np.eye(3) - uu)
    return spatial_inertia_of_points(masses, strips.centers) + out_rot


def tube_rigid_inertia(strips: Strips, mass: float) -> np.ndarray:
    """6x6 rigid-body inertia about the body origin of a uniform thin tube of the given mass."""
    masses, out_rot = [], np.zeros((6, 6))
    r = strips.radius
    for u, ell in zip(strips.axes, strips.lengths, strict=True):
        m = mass * ell / strips.total_length
        uu = np.outer(u, u)
        masses.append(m * np.eye(3))
        out_rot[3:, 3:] += m * (3 * r**2 + ell**2) / 12 * (np.eye(3) - uu) + m * r**2 / 2 * uu
    return spatial_inertia_of_points(masses, strips.centers) + out_rot


def kirchhoff_coriolis(m6: Sym, v: Sym) -> Sym:
    """C(V) V for a 6x6 symmetric inertia (rigid or added): [w x p; v x p + w x l]."""
    mom = m6 @ v
    lin, ang = v[:3], v[3:]
    return cs.vertcat(cs.cross(ang, mom[:3]), cs.cross(lin, mom[:3]) + cs.cross(ang, mom[3:]))


def current_twist_rate(omega: Sym, v_c_body: Sym) -> Sym:
    """Rate of the body-frame current twist [R^T v_c; 0] for a constant inertial current."""
    return cs.vertcat(-cs.cross(omega, v_c_body), 0 * omega)


def _abs(x: Sym) -> Sym:
    return cs.sqrt(x * x + _EPS**2)


def diagonal_damping(v_r: Sym, d_lin: Sym, d_quad: Sym) -> Sym:
    """D(V_r) V_r with D = diag(d_lin) + diag(d_quad) |V_r| (Fossen): the resisting term (LHS)."""
    return d_lin * v_r + d_quad * _abs(v_r) * v_r


def strip_damping(v_r: Sym, strips: Strips, coef: TubeCoefficients, scale: Sym) -> Sym:
    """Resisting wrench (LHS sign) of drag integrated over the strips, about the body origin."""
    return strip_drag(
        v_r,
        [cs.DM(r) for r in strips.centers],
        [cs.DM(u) for u in strips.axes],
        [float(ell) for ell in strips.lengths],
        (coef.drag_cross, coef.drag_axial, coef.drag_linear),
        scale,
    )


def strip_drag(
    v_r: Sym,
    centers: Sequence[Any],
    axes: Sequence[Any],
    lengths: Sequence[Any],
    drag: tuple[Any, Any, Any],
    scale: Sym,
) -> Sym:
    """``strip_damping`` of strips given as numbers or symbols: each strip's centre and
    unit axis (3-vectors) and length, and the per-metre drag (cross-flow, axial, linear).
    Symbols make the strips an input of a compiled function (the object's, one library
    for every object); a strip of length 0 adds exactly nothing."""
    drag_cross, drag_axial, drag_linear = drag
    lin, ang = v_r[:3], v_r[3:]
    force = 0
    moment = 0
    for r, u, ell in zip(centers, axes, lengths, strict=True):
        vs = lin + cs.cross(ang, r)
        va = cs.dot(u, vs)
        vp = vs - va * u
        speed_p = cs.sqrt(cs.dot(vp, vp) + _EPS**2)
        f = ell * (drag_cross * speed_p * vp + drag_axial * _abs(va) * va * u + drag_linear * vs)
        force = force + f
        moment = moment + cs.cross(r, f)
    return scale * cs.vertcat(force, moment)
