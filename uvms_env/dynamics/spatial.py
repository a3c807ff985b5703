"""Rotations, Euler-angle kinematics and skew matrices, written once for numpy and CasADi.

Every function takes and returns CasADi expressions (SX or MX) and also accepts numpy
arrays (evaluated through CasADi's DM), so the simulator, the controller and the tests
share one implementation of the conventions: ZYX Euler angles (Fossen),
R = Rz(psi) Ry(theta) Rx(phi), and eta_dot = blkdiag(R, T) nu.
"""

from __future__ import annotations

import math
from typing import Any

import casadi as cs
import numpy as np

# Pitch this close to +-pi/2 makes ZYX Euler-angle rates stiff without bound: the simulator
# reports a period that fails there as reaching the representation's singularity, and no
# scenario may start or pass a waypoint there.
SINGULARITY_MARGIN = 0.1  # rad

Sym = cs.SX | cs.MX | cs.DM


def skew(v: Sym) -> Sym:
    """S(v) with S(v) w = v x w."""
    return cs.vertcat(
        cs.horzcat(0, -v[2], v[1]),
        cs.horzcat(v[2], 0, -v[0]),
        cs.horzcat(-v[1], v[0], 0),
    )


def vee(m: Sym) -> Sym:
    """Inverse of skew on the skew-symmetric part of a 3x3 matrix."""
    return 0.5 * cs.vertcat(m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1])


def rot_zyx(theta: Sym) -> Sym:
    """Rotation body -> inertial for ZYX Euler angles [phi, theta, psi]."""
    cf, sf = cs.cos(theta[0]), cs.sin(theta[0])
    ct, st = cs.cos(theta[1]), cs.sin(theta[1])
    cp, sp = cs.cos(theta[2]), cs.sin(theta[2])
    return cs.vertcat(
        cs.horzcat(cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
        cs.horzcat(sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
        cs.horzcat(-st, ct * sf, ct * cf),
    )


def euler_rate_matrix(theta: Sym) -> Sym:
    """T(Theta): body angular velocity -> ZYX Euler-angle rates (singular at |theta| = pi/2)."""
    cf, sf = cs.cos(theta[0]), cs.sin(theta[0])
    ct, tt = cs.cos(theta[1]), cs.tan(theta[1])
    return cs.vertcat(
        cs.horzcat(1, sf * tt, cf * tt),
        cs.horzcat(0, cf, -sf),
        cs.horzcat(0, sf / ct, cf / ct),
    )


def homogeneous(p: Sym, r: Sym) -> Sym:
    """4x4 transform from a position and a rotation."""
    return cs.vertcat(cs.horzcat(r, p), cs.horzcat(0, 0, 0, 1))


def rotation_error(r: Sym, r_target: Sym) -> Sym:
    """Small-angle rotation error (inertial frame) that takes r_target to r."""
    return vee(r @ r_target.T)


def wrap_angle(a: Any, xp: Any = np) -> Any:
    """Angles wrapped into (-pi, pi], elementwise, for numpy (``xp=np``) or CuPy arrays.

    The one array wrap of the package: its CasADi twin is ``wrap_angle_sx`` (the same
    floor formula, so compiled kernels and array code agree to rounding)."""
    b = math.pi - xp.asarray(a, dtype=float) if xp is np else math.pi - a
    return math.pi - (b - 2.0 * math.pi * xp.floor(b / (2.0 * math.pi)))


def wrap_angle_sx(a: Sym) -> Sym:
    """``wrap_angle`` for CasADi expressions (derivative 1 wherever the wrap is continuous)."""
    b = math.pi - a
    return math.pi - (b - 2.0 * math.pi * cs.floor(b / (2.0 * math.pi)))
