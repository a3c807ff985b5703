"""Properties of the single-UVMS and object dynamics (no closed chain)."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from uvms_env.dynamics import PARAMETER_LAYOUT
from uvms_env.dynamics.local_model import euler_zyx
from uvms_env.dynamics.payload import OBJECT_PARAMETER_LAYOUT
from uvms_env.dynamics.spatial import homogeneous, rot_zyx
from uvms_env.models import URDF_PATH, render_urdf


def _frame_pose(uvms, frame: str) -> cs.Function:
    """Inertial pose (p, R) of a URDF frame ("vehicle", "arm_base", "link_i", "ee")."""
    q = cs.SX.sym("q", 10)
    base = homogeneous(q[:3], rot_zyx(q[3:6]))
    if frame == "vehicle":
        return cs.Function("vehicle_pose", [q], [q[:3], base[:3, :3]])
    p, r = uvms._fk(frame, base, q[6:])
    return cs.Function(f"{frame}_pose", [q], [p, r])


def _unforced_acceleration(uvms, q, zeta, p) -> np.ndarray:
    """zeta_dot of a free UVMS (no grasp) with zero inputs, in still water."""
    m, h = uvms.dynamics(q, zeta, np.zeros(3), p)
    return np.linalg.solve(np.array(m), -np.array(h).ravel())


def random_q(rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-1.2, 1.2, 3), rng.uniform(-2, 2, 4)])


def test_committed_urdf_is_the_rendering_of_the_parameter_file():
    assert URDF_PATH.read_text() == render_urdf()


def _differentiated_motion(uvms, frame: str) -> cs.Function:
    """The independent computation ``chain_motion`` replaces: ``frame``'s body twist from
    its forward kinematics differentiated along q_dot = T(q) zeta, its Jacobian in zeta and
    Jdot zeta by differentiating that again; and the inertial [p_dot; omega] of the frame."""
    q, zeta = cs.SX.sym("q", 10), cs.SX.sym("zeta", 10)
    qdot = uvms.qdot_map(q) @ zeta
    p, r = _frame_pose(uvms, frame)(q)
    rdot = cs.reshape(cs.jtimes(cs.reshape(r, 9, 1), q, qdot), 3, 3)
    spin = rdot @ r.T
    omega = 0.5 * cs.vertcat(
        spin[2, 1] - spin[1, 2], spin[0, 2] - spin[2, 0], spin[1, 0] - spin[0, 1]
    )
    v_w = cs.jtimes(p, q, qdot)
    body = cs.vertcat(r.T @ v_w, r.T @ omega)
    world = cs.vertcat(v_w, omega)
    outputs = [body, cs.jacobian(body, zeta), cs.jtimes(body, q, qdot)]
    outputs += [cs.jacobian(world, zeta), cs.jtimes(world, q, qdot)]
    return cs.Function(f"{frame}_motion", [q, zeta], outputs)


def test_the_chains_pass_equals_differentiated_forward_kinematics(uvms, rng):
    q_s, zeta_s = cs.SX.sym("q", 10), cs.SX.sym("zeta", 10)
    chain = uvms.chain_motion(q_s[6:], zeta_s)
    passed = cs.Function("chain", [q_s, zeta_s], [x for _, *m in chain for x in m])
    frames = ("link_1", "link_2", "link_3", "link_4", "ee")
    references = [_differentiated_motion(uvms, f) for f in frames]
    for _ in range(20):
        q, zeta = random_q(rng), rng.normal(size=10)
        got = [np.array(x) for x in passed(q, zeta)]
        for k, ref in enumerate(references):
            body, jac, jdot, jac_world, jdot_world = (np.array(x) for x in ref(q, zeta))
            for mine, theirs in zip(got[3 * k : 3 * k + 3], (body, jac, jdot), strict=True):
                np.testing.assert_allclose(mine, theirs, rtol=1e-11, atol=1e-11)
        # the end effector's inertial Jacobian, its rate and the manipulability built on it
        np.testing.assert_allclose(np.array(uvms.ee_jacobian(q)), jac_world, atol=1e-11)
        np.testing.assert_allclose(
            np.array(uvms.ee_jdot_zeta(q, zeta)), jdot_world, rtol=1e-11, atol=1e-11
        )
        jbar = jac_world[:, [0, 1, 2, 5, 6, 7, 8, 9]]
        manipulability = float(uvms.manipulability(q))
        assert manipulability == pytest.approx(np.linalg.det(jbar @ jbar.T), rel=1e-10)


def test_mass_matrix_symmetric_positive_definite(uvms, rng):
    p = uvms.nominal_parameters()
    for _ in range(50):
        m = np.array(uvms.mass_matrix(random_q(rng), p))
        assert np.allclose(m, m.T, atol=1e-12)
        assert np.linalg.eigvalsh(m).min() > 1e-3


def _link_kinetic_energy(uvms, q: np.ndarray, zeta: np.ndarray, eps: float = 1e-6) -> float:
    """Independent kinetic energy: sum over bodies of 0.5 m v_c^2 + 0.5 w^T I_c w, with the
    velocities from central differences of the link poses along q_dot = T(q) zeta and the
    inertias read from the URDF file."""
    import xml.etree.ElementTree as ET

    qdot = np.array(uvms.qdot_matrix(q)).dot(zeta)
    energy = 0.0
    for link in ET.fromstring(render_urdf()).iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = float(inertial.find("mass").get("value"))
        com = np.array(inertial.find("origin").get("xyz").split(), dtype=float)
        i = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
        inertia = np.array(
            [
                [i["ixx"], i["ixy"], i["ixz"]],
                [i["ixy"], i["iyy"], i["iyz"]],
                [i["ixz"], i["iyz"], i["izz"]],
            ]
        )
        pose = _frame_pose(uvms, link.get("name"))
        (pp, rp), (pm, rm), (_, r0) = pose(q + eps * qdot), pose(q - eps * qdot), pose(q)
        rp, rm, r0 = np.array(rp), np.array(rm), np.array(r0)
        pdot = (np.array(pp).ravel() + rp @ com - np.array(pm).ravel() - rm @ com) / (2 * eps)
        w_skew = r0.T @ (rp - rm) / (2 * eps)  # body angular velocity
        w = np.array([w_skew[2, 1], w_skew[0, 2], w_skew[1, 0]])
        energy += 0.5 * mass * pdot @ pdot + 0.5 * w @ inertia @ w
    armature = np.array(uvms.params.arm.armature)
    return energy + 0.5 * armature @ zeta[6:] ** 2


def test_rigid_kinetic_energy_matches_independent_sum_over_links(uvms, rng):
    p = uvms.nominal_parameters()
    p[PARAMETER_LAYOUT["vehicle_added_mass"]] = 0.0
    p[PARAMETER_LAYOUT["arm_added_mass_scale"]] = 0.0
    for _ in range(5):
        q, zeta = random_q(rng), rng.normal(size=10)
        m = np.array(uvms.mass_matrix(q, p))
        assert 0.5 * zeta @ m @ zeta == pytest.approx(_link_kinetic_energy(uvms, q, zeta), rel=1e-6)


def test_power_of_coriolis_and_added_mass_terms_vanishes(uvms, rng):
    """With damping, current and gravity effects removed, zeta^T h = 0.5 d/dt(zeta^T M zeta)
    at constant zeta: the Coriolis terms (rigid, added mass, Kirchhoff) do no work."""
    p = uvms.nominal_parameters()
    for name in (
        "vehicle_damping_linear",
        "vehicle_damping_quadratic",
        "arm_drag_scale",
        "joint_damping",
    ):
        p[PARAMETER_LAYOUT[name]] = 0.0
    for _ in range(10):
        q, zeta = random_q(rng), rng.normal(size=10) * 0.3
        _, h = uvms.dynamics(q, zeta, np.zeros(3), p)
        _, g = uvms.dynamics(q, np.zeros(10), np.zeros(3), p)
        qdot = np.array(uvms.qdot_matrix(q)).dot(zeta)
        eps = 1e-6
        dm = (
            np.array(uvms.mass_matrix(q + eps * qdot, p))
            - np.array(uvms.mass_matrix(q - eps * qdot, p))
        ) / (2 * eps)
        coriolis = np.array(h - g).ravel()
        # Lagrangian identity: zeta^T (C zeta) = 0.5 zeta^T Mdot zeta
        assert zeta @ coriolis == pytest.approx(0.5 * zeta @ dm @ zeta, abs=1e-6)


def test_damping_dissipates(uvms, rng):
    p = uvms.nominal_parameters()
    for _ in range(20):
        q, zeta = random_q(rng), rng.normal(size=10)
        _, h = uvms.dynamics(q, zeta, np.zeros(3), p)
        p0 = p.copy()
        for name in (
            "vehicle_damping_linear",
            "vehicle_damping_quadratic",
            "arm_drag_scale",
            "joint_damping",
        ):
            p0[PARAMETER_LAYOUT[name]] = 0.0
        _, h0 = uvms.dynamics(q, zeta, np.zeros(3), p0)
        assert zeta @ np.array(h - h0).ravel() > 0  # damping power is positive on the LHS


def test_heavier_than_water_sinks_and_lighter_floats(uvms, bar):
    q, zeta = np.zeros(10), np.zeros(10)
    p = uvms.nominal_parameters()
    acc = _unforced_acceleration(uvms, q, zeta, p)
    assert acc[2] > 0  # NED: +z is down, the vehicle is 0.98 N heavy
    p[PARAMETER_LAYOUT["vehicle_displaced_volume"]] *= 1.05
    acc = _unforced_acceleration(uvms, q, zeta, p)
    assert acc[2] < 0
    po = bar.nominal_parameters()
    m_o, h_o = bar.dynamics(np.zeros(6), np.zeros(6), np.zeros(3), po)
    assert np.linalg.solve(np.array(m_o), -np.array(h_o).ravel())[2] > 0
    po[OBJECT_PARAMETER_LAYOUT["displaced_volume"]] *= 1.1
    m_o, h_o = bar.dynamics(np.zeros(6), np.zeros(6), np.zeros(3), po)
    assert np.linalg.solve(np.array(m_o), -np.array(h_o).ravel())[2] < 0


def test_tilted_vehicle_rights_itself(uvms):
    """Released at 0.4 rad roll and pitch, the free UVMS returns towards level (B above G)."""
    p = uvms.nominal_parameters()
    q = np.zeros(10)
    q[3], q[4] = 0.4, -0.4
    x = np.concatenate([q, np.zeros(10)])

    def f(x):
        qq, zz = x[:10], x[10:]
        acc = _unforced_acceleration(uvms, qq, zz, p)
        return np.concatenate([np.array(uvms.qdot_matrix(qq)).dot(zz), acc])

    dt = 0.02
    for _ in range(1500):  # 30 s, RK4
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert abs(x[3]) < 0.1 and abs(x[4]) < 0.1


def test_euler_round_trip(rng):
    for _ in range(20):
        theta = rng.uniform([-3, -1.4, -3], [3, 1.4, 3])
        assert np.allclose(np.array(euler_zyx(rot_zyx(cs.DM(theta)))).ravel(), theta)
