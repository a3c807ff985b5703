"""Grasp geometry and inverse kinematics: place each UVMS so that it holds the object."""

from __future__ import annotations

from functools import cache

import casadi as cs
import numpy as np

from uvms_env.dynamics import ObjectModel, UVMSModel
from uvms_env.dynamics.payload import grasp_jacobian
from uvms_env.dynamics.spatial import rot_zyx, rotation_error
from uvms_env.dynamics.uvms import default_model

# Nominal arm pose for holding: gripper forward-down, every joint >= 1.2 rad from its limit.
NOMINAL_ARM = np.array([0.0, 0.8, 0.4, 0.0])


def uvms_model() -> UVMSModel:
    """The shared symbolic UVMS model of the parameter file."""
    return default_model()


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def nominal_hand() -> tuple[np.ndarray, np.ndarray]:
    """End-effector position and rotation in the vehicle frame at the nominal arm pose."""
    q = np.concatenate([np.zeros(6), NOMINAL_ARM])
    p, r = uvms_model().ee_pose(q)
    return np.array(p).ravel(), np.array(r)


def robot_radius() -> float:
    """r_bar: radius of the ball centred at the end effector that holds its UVMS's hull box
    at the nominal arm pose (the paper's B(p_i, r_bar))."""
    p_ee, _ = nominal_hand()
    half = np.asarray(uvms_model().params.vehicle.box) / 2
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    return float(np.max(np.linalg.norm(corners - p_ee, axis=1)))


def grasp_rotation(yaw: float) -> np.ndarray:
    """R_Oi for a robot heading ``yaw`` in the object frame at the nominal arm pose."""
    return _rz(yaw) @ nominal_hand()[1]


def nominal_configuration(x_o: np.ndarray, offset: np.ndarray, yaw: float) -> np.ndarray:
    """Level vehicle, nominal arm, exact grasp when the object itself is level."""
    p_ee, _ = nominal_hand()
    r_o = np.array(rot_zyx(x_o[3:]))
    r_yaw = _rz(x_o[5]) @ _rz(yaw)
    pos = x_o[:3] + r_o @ offset - r_yaw @ p_ee
    return np.concatenate([pos, [0.0, 0.0, x_o[5] + yaw], NOMINAL_ARM])


@cache
def _ik_functions() -> tuple[cs.Function, cs.Function]:
    model = uvms_model()
    q = cs.SX.sym("q", 10)
    p_t, r_t = cs.SX.sym("p_t", 3), cs.SX.sym("r_t", 3, 3)
    p, r = model.ee_pose(q)
    res = cs.vertcat(p - p_t, rotation_error(r, r_t))
    return (
        cs.Function("ik_res", [q, p_t, r_t], [res]),
        cs.Function("ik_jac", [q, p_t, r_t], [cs.jacobian(res, q)]),
    )


def solve_grasp_ik(
    x_o: np.ndarray, offset: np.ndarray, r_oi: np.ndarray, q0: np.ndarray, tol: float = 1e-12
) -> np.ndarray:
    """Configuration closest to q0 (weighted) whose end effector holds the grasp exactly.

    Weighted minimum-norm Gauss-Newton steps: roll and pitch (passive) are expensive to
    move, joints cheap, so the arm absorbs the object's tilt.
    """
    res_f, jac_f = _ik_functions()
    r_o = np.array(rot_zyx(x_o[3:]))
    p_t, r_t = x_o[:3] + r_o @ offset, r_o @ r_oi
    w_inv = np.diag([1.0, 1.0, 1.0, 0.05, 0.05, 1.0, 4.0, 4.0, 4.0, 4.0])
    q = np.array(q0, dtype=float)
    for _ in range(50):
        res = np.array(res_f(q, p_t, r_t)).ravel()
        if np.linalg.norm(res) < tol:
            return q
        jac = np.array(jac_f(q, p_t, r_t))
        q = q - w_inv @ jac.T @ np.linalg.solve(jac @ w_inv @ jac.T, res)
    raise ValueError(
        f"grasp inverse kinematics did not converge (residual {np.linalg.norm(res):.2e})"
    )


def static_equilibrium(
    x_o: np.ndarray,
    offsets: np.ndarray,
    rotations: np.ndarray,
    q_guess: np.ndarray,
    object_model: ObjectModel,
) -> tuple[np.ndarray, np.ndarray]:
    """Start configurations (N, 10) that hold the grasps exactly AND can be held at rest,
    with the holding inputs (N, 8) of least normalized effort.

    Roll and pitch are passive: with a slightly heavy object the vehicles must pitch until
    their restoring moment balances the load, so the level IK pose is not an equilibrium.
    Solved as one small NLP (IPOPT): minimize |tau / tau_max|^2 + 0.1 |q - q_guess|^2
    subject to the grasp constraints and the static balance of every body.
    """
    model = uvms_model()
    n = len(offsets)
    tau_max = model.params.limits.tau_max
    q = cs.SX.sym("q", 10, n)
    tau = cs.SX.sym("tau", 8, n)
    lam = cs.SX.sym("lam", 6, n)
    p_nom = model.nominal_parameters()
    res_f, _ = _ik_functions()
    r_o = np.array(rot_zyx(x_o[3:]))
    g, obj_wrench = [], 0
    for i in range(n):
        p_t, r_t = x_o[:3] + r_o @ offsets[i], r_o @ rotations[i]
        g.append(res_f(q[:, i], p_t, r_t))
        _, h = model.dynamics(q[:, i], np.zeros(10), np.zeros(3), p_nom)
        jac = model.ee_jacobian(q[:, i])
        g.append(cs.DM(model.B) @ tau[:, i] - jac.T @ lam[:, i] - h)
        obj_wrench = obj_wrench + grasp_jacobian(cs.DM(r_o), offsets[i]).T @ lam[:, i]
    _, h_o = object_model.dynamics(x_o, np.zeros(6), np.zeros(3), object_model.nominal_parameters())
    g.append(obj_wrench - h_o)
    cost = cs.sumsqr(tau / cs.repmat(cs.DM(tau_max), 1, n)) + 0.1 * cs.sumsqr(q - q_guess.T)
    z = cs.vertcat(cs.vec(q), cs.vec(tau), cs.vec(lam))
    solver = cs.nlpsol(
        "equilibrium",
        "ipopt",
        {"x": z, "f": cost, "g": cs.vertcat(*g)},
        {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False, "ipopt.tol": 1e-12},
    )
    z0 = np.concatenate([q_guess.reshape(-1), np.zeros(14 * n)])
    sol = solver(x0=z0, lbg=0, ubg=0)
    if not solver.stats()["success"]:
        raise ValueError("no static equilibrium holding the grasps was found for this scenario")
    zz = np.array(sol["x"]).ravel()
    q_eq = zz[: 10 * n].reshape(n, 10)
    tau_eq = zz[10 * n : 18 * n].reshape(n, 8)
    return q_eq, tau_eq
