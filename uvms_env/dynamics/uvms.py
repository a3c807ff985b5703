"""Dynamics of one UVMS (vehicle + 4-DoF arm) as CasADi functions of (q, zeta, tau, v_c, p).

    M(q, p) zeta_dot + h(q, zeta, v_c, p) = B tau  (- J(q)^T lambda, added by the simulator)

q = [x y z phi theta psi, q_1..q_4] (NED, ZYX Euler), zeta = [u v w p q r, qdot_1..4],
tau = [X Y Z N, tau_1..4]. Rigid body by adam-robotics, hydrodynamics in ``hydro``,
restoring terms from one potential (g(q) = T(q)^T dV/dq, so the potential in ``energy``
and the forces cannot disagree), end-effector kinematics in the inertial frame.
Reference: docs/model.md, "One UVMS (paper eq6)".

``p`` holds the physical numbers that a scenario may perturb (parameter mismatch,
damping scale); ``nominal_parameters()`` gives the parameter file's values.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import casadi as cs
import numpy as np
from adam import Representations
from adam.casadi import KinDynComputations

from uvms_env.dynamics.hydro import (
    Strips,
    TubeCoefficients,
    current_twist_rate,
    diagonal_damping,
    kirchhoff_coriolis,
    strip_damping,
    tube_added_mass,
)
from uvms_env.dynamics.spatial import euler_rate_matrix, homogeneous, rot_zyx, skew
from uvms_env.models import Parameters, load_parameters, render_urdf
from uvms_env.models.urdf import JOINT_NAMES, LINK_NAMES, chain_origins, dh_tail

NQ = 10  # generalized coordinates / velocities of one UVMS
NU = 8  # inputs: surge, sway, heave, yaw, 4 joint torques
ACTUATED_DOFS = (0, 1, 2, 5, 6, 7, 8, 9)  # zeta components driven by tau (roll, pitch passive)

# Layout of the per-robot physical parameter vector p.
PARAMETER_LAYOUT: dict[str, slice] = {
    "vehicle_added_mass": slice(0, 6),
    "vehicle_damping_linear": slice(6, 12),
    "vehicle_damping_quadratic": slice(12, 18),
    "vehicle_displaced_volume": slice(18, 19),
    "vehicle_extra_mass": slice(19, 20),
    "arm_added_mass_scale": slice(20, 21),
    "arm_drag_scale": slice(21, 22),
    "joint_damping": slice(22, 26),
}
NP = 26
DAMPING_ENTRIES = (
    "vehicle_damping_linear",
    "vehicle_damping_quadratic",
    "arm_drag_scale",
    "joint_damping",
)


def _unit(rows: int, columns: int, i: int, j: int) -> np.ndarray:
    out = np.zeros((rows, columns))
    out[i, j] = 1.0
    return out


def actuation_matrix() -> np.ndarray:
    """B (10x8): inputs to generalized forces; roll and pitch are passive."""
    b = np.zeros((NQ, NU))
    for k, dof in enumerate(ACTUATED_DOFS):
        b[dof, k] = 1.0
    return b


@dataclass(frozen=True)
class LinkHydro:
    name: str
    strips: Strips
    coef: TubeCoefficients
    added_mass: np.ndarray  # 6x6 about the link frame origin, nominal


class UVMSModel:
    """Symbolic model of one UVMS. Build once (a second or two); the functions are reusable.

    Attributes are CasADi ``Function`` objects (SX, so they inline into larger graphs):
    ``dynamics(q, zeta, v_c, p) -> (M, h)``, ``mass_matrix(q, p)``,
    ``bias(q, zeta, v_c, p)``, ``ee_pose(q) -> (p, R)``, ``ee_jacobian(q) -> J``,
    ``ee_jdot_zeta(q, zeta)``, ``potential(q, p)``, ``manipulability(q)``,
    ``body_points(q) -> 3xK`` (vehicle centre, arm joints, end effector).
    """

    def __init__(self, params: Parameters | None = None) -> None:
        self.params = params or load_parameters()
        prm = self.params
        self.B = actuation_matrix()
        self.kindyn = KinDynComputations(render_urdf(prm), list(JOINT_NAMES), gravity=np.zeros(6))
        self.kindyn.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
        self.links = self._link_hydro()

        q, zeta = cs.SX.sym("q", NQ), cs.SX.sym("zeta", NQ)
        v_c, p = cs.SX.sym("v_c", 3), cs.SX.sym("p", NP)
        pos, theta, qm = q[:3], q[3:6], q[6:]
        rot = rot_zyx(theta)
        base = homogeneous(pos, rot)

        m_rb = self.kindyn.mass_matrix(base, qm) + cs.diag(
            cs.vertcat(cs.DM.zeros(6), cs.DM(prm.arm.armature))
        )
        h_rb = self.kindyn.coriolis_term(base, qm, zeta[:6], zeta[6:])

        m_veh, h_veh = self._vehicle_hydro(zeta[:6], rot, v_c, p)
        mass = m_rb + cs.diagcat(m_veh, cs.DM.zeros(4, 4))
        bias = h_rb + cs.vertcat(h_veh, p[PARAMETER_LAYOUT["joint_damping"]] * zeta[6:])
        chain = self.chain_motion(qm, zeta)
        mass, bias = self._add_arm_hydro(mass, bias, chain, rot.T @ v_c, p)

        pot = self._potential(base, qm, p)
        bias = bias + self.qdot_map(q).T @ cs.gradient(pot, q)
        mass = 0.5 * (mass + mass.T)  # exact symmetry despite round-off in the sums

        p_ee, r_ee = self._fk("ee", base, qm)
        # the end effector's body motion, turned into the inertial frame: the velocity of
        # its point and its angular velocity, J_ee = blkdiag(R, R) J^b; at zeta_dot = 0 their
        # rates are R (w^b x v^b + a_v^b) and R a_w^b (R_dot = R [w^b]x)
        _, v_b, j_b, a_b = chain[-1]
        rot2 = cs.diagcat(r_ee, r_ee)
        j_ee = rot2 @ j_b
        jdot_zeta = rot2 @ cs.vertcat(cs.cross(v_b[3:], v_b[:3]) + a_b[:3], a_b[3:])
        # det(Jbar Jbar^T) is the same in the end effector's axes (a rotation's det is 1)
        jbar = j_b[:, list(ACTUATED_DOFS)]

        points = [pos] + [self._fk(n, base, qm)[0] for n in (*LINK_NAMES, "ee")]

        self.dynamics = cs.Function("uvms_dynamics", [q, zeta, v_c, p], [mass, bias])
        self.mass_matrix = cs.Function("uvms_mass", [q, p], [mass])
        self.bias = cs.Function("uvms_bias", [q, zeta, v_c, p], [bias])
        self.potential = cs.Function("uvms_potential", [q, p], [pot])
        self.ee_pose = cs.Function("ee_pose", [q], [p_ee, r_ee])
        self.ee_jacobian = cs.Function("ee_jacobian", [q], [j_ee])
        self.ee_jdot_zeta = cs.Function("ee_jdot_zeta", [q, zeta], [jdot_zeta])
        self.manipulability = cs.Function("manipulability", [q], [cs.det(jbar @ jbar.T)])
        self.body_points = cs.Function("body_points", [q], [cs.horzcat(*points)])
        self.qdot_matrix = cs.Function("qdot_matrix", [q], [self.qdot_map(q)])

    def _vehicle_hydro(self, nu: cs.SX, rot: cs.SX, v_c: cs.SX, p: cs.SX) -> tuple[cs.SX, cs.SX]:
        """The vehicle's hydrodynamic mass and bias and its mass mismatch (an extra rigid
        mass at r_g = origin, which Kirchhoff's form describes exactly)."""
        prm = self.params
        vc_body = rot.T @ v_c
        nu_r = nu - cs.vertcat(vc_body, cs.DM.zeros(3))
        m_a = cs.diag(p[PARAMETER_LAYOUT["vehicle_added_mass"]])
        dm = p[PARAMETER_LAYOUT["vehicle_extra_mass"]]
        inertia = cs.DM(prm.vehicle.inertia) / prm.vehicle.mass
        m_extra = cs.diag(cs.vertcat(dm, dm, dm, dm * inertia))
        h_veh = (
            m_a @ (-current_twist_rate(nu[3:], vc_body))
            + kirchhoff_coriolis(m_a, nu_r)
            + kirchhoff_coriolis(m_extra, nu)
            + diagonal_damping(
                nu_r,
                p[PARAMETER_LAYOUT["vehicle_damping_linear"]],
                p[PARAMETER_LAYOUT["vehicle_damping_quadratic"]],
            )
        )
        return m_a + m_extra, h_veh

    def chain_motion(self, qm: cs.SX, zeta: cs.SX) -> list[tuple[cs.SX, cs.SX, cs.SX, cs.SX]]:
        """(R, V, J, a) of links 1..4 and the end effector, one pass out from the vehicle:
        R the frame's rotation from its parent, V its body twist (velocity of its origin,
        angular velocity; its own axes), J = dV/dzeta (6 x 10), a = J_dot zeta (V's rate at
        zeta_dot = 0). Each frame sits at its origin in its parent (``chain_origins``),
        turned by its joint about z: V = Ad^-1 V_parent + s qdot, a = Ad^-1 a_parent + V x s
        qdot (s = the z rotation). The vehicle's V is zeta[:6] and its a is 0."""
        v, w = zeta[:3], zeta[3:6]
        jv = cs.DM(np.eye(3, NQ))
        jw = cs.DM(np.eye(3, NQ, 3))
        av, aw = cs.DM.zeros(3), cs.DM.zeros(3)
        mount, *joints, tip = chain_origins(self.params)
        out = []
        for k, (xyz, rpy) in enumerate([*joints, tip]):
            rot = cs.DM(rot_zyx(rpy))
            if k == 0:  # joint 1's origin is the mount's frame
                rot = cs.DM(rot_zyx(mount[1])) @ rot
                xyz = mount[0] + np.asarray(cs.DM(rot_zyx(mount[1]))) @ xyz
            if k < len(joints):  # a joint turns the frame by q about its z
                c, s = cs.cos(qm[k]), cs.sin(qm[k])
                rot = rot @ cs.vertcat(
                    cs.horzcat(c, -s, 0), cs.horzcat(s, c, 0), cs.horzcat(0, 0, 1)
                )
            rt, arm = rot.T, cs.DM(skew(xyz))
            v, w = rt @ (v - arm @ w), rt @ w
            jv, jw = rt @ (jv - arm @ jw), rt @ jw
            av, aw = rt @ (av - arm @ aw), rt @ aw
            if k < len(joints):
                spin = cs.vertcat(0, 0, zeta[6 + k])
                w = w + spin
                jw = jw + cs.DM(_unit(3, NQ, 2, 6 + k))  # the joint's rate turns it about z
                av = av + cs.cross(v, spin)
                aw = aw + cs.cross(w, spin)
            out.append((rot, cs.vertcat(v, w), cs.vertcat(jv, jw), cs.vertcat(av, aw)))
        return out

    def _add_arm_hydro(
        self,
        mass: cs.SX,
        bias: cs.SX,
        chain: list[tuple[cs.SX, cs.SX, cs.SX, cs.SX]],
        vc_body: cs.SX,
        p: cs.SX,
    ) -> tuple[cs.SX, cs.SX]:
        """``mass`` and ``bias`` plus the arm links' hydrodynamics: strip theory in each
        link frame, on the links' body motion (``chain_motion``) and the current in the
        link's axes (``vc_body``, the current in the vehicle's, turned down the chain)."""
        am_scale = p[PARAMETER_LAYOUT["arm_added_mass_scale"]]
        drag_scale = p[PARAMETER_LAYOUT["arm_drag_scale"]]
        v_c = vc_body
        for link, (rot, v_l, j_l, jdot_l) in zip(self.links, chain[:-1], strict=True):
            v_c = rot.T @ v_c
            v_r = v_l - cs.vertcat(v_c, cs.DM.zeros(3))
            m_al = am_scale * cs.DM(link.added_mass)
            wrench = (
                m_al @ (jdot_l - current_twist_rate(v_l[3:], v_c))
                + kirchhoff_coriolis(m_al, v_r)
                + strip_damping(v_r, link.strips, link.coef, drag_scale)
            )
            mass = mass + j_l.T @ m_al @ j_l
            bias = bias + j_l.T @ wrench
        return mass, bias

    # -- helpers -----------------------------------------------------------------------
    @staticmethod
    def qdot_map(q: cs.SX) -> cs.SX:
        """T(q) with q_dot = T(q) zeta: blkdiag(R(Theta), T(Theta), I_4)."""
        return cs.diagcat(rot_zyx(q[3:6]), euler_rate_matrix(q[3:6]), cs.SX.eye(4))

    def _fk(self, frame: str, base: cs.SX, qm: cs.SX) -> tuple[cs.SX, cs.SX]:
        h = self.kindyn.forward_kinematics(frame, base, qm)
        return h[:3, 3], h[:3, :3]

    def _link_hydro(self) -> list[LinkHydro]:
        arm, rho = self.params.arm, self.params.water_density
        out = []
        for name, mass, row in zip(LINK_NAMES, arm.link_mass, arm.dh, strict=True):
            tail, _ = dh_tail(*row)
            length = float(np.linalg.norm(tail))
            strips = Strips.along([(np.zeros(3), tail)], arm.tube_radius, per_segment=3)
            coef = TubeCoefficients.for_tube(
                arm.tube_radius,
                mass / length,
                rho,
                arm.drag_coefficient,
                arm.axial_added_mass_fraction,
                arm.axial_drag_coefficient,
                arm.linear_drag_per_length,
            )
            out.append(LinkHydro(name, strips, coef, tube_added_mass(strips, coef)))
        return out

    def arm_volumes(self) -> tuple[float, list[float]]:
        """Displaced volumes of the base housing and links, trimmed neutral if configured."""
        arm, rho = self.params.arm, self.params.water_density
        if arm.trim_neutral:
            return arm.base_housing_mass / rho, [m / rho for m in arm.link_mass]
        return arm.base_housing_volume, list(arm.link_volume)

    def _potential(self, base: cs.SX, qm: cs.SX, p: cs.SX) -> cs.SX:
        """Gravity + buoyancy potential (NED: depth z is down, so weight has potential -W z)."""
        prm = self.params
        g, rho = prm.gravity, prm.water_density
        rot, pos = base[:3, :3], base[:3, 3]
        weight = (prm.vehicle.mass + p[PARAMETER_LAYOUT["vehicle_extra_mass"]]) * g
        buoy = rho * g * p[PARAMETER_LAYOUT["vehicle_displaced_volume"]]
        z_g = pos[2] + (rot @ cs.DM(prm.vehicle.center_of_gravity))[2]
        z_b = pos[2] + (rot @ cs.DM(prm.vehicle.center_of_buoyancy))[2]
        pot = -weight * z_g + buoy * z_b
        # Arm bodies: weight and buoyancy both at the body's centre of gravity.
        v_housing, v_links = self.arm_volumes()
        arm = prm.arm
        bodies = [("arm_base", arm.base_housing_mass, v_housing, np.zeros(3))]
        for name, mass, vol, row in zip(LINK_NAMES, arm.link_mass, v_links, arm.dh, strict=True):
            bodies.append((name, mass, vol, dh_tail(*row)[0] / 2))
        for name, mass, vol, com in bodies:
            net = (mass - rho * vol) * g
            if abs(net) > 1e-12:
                p_l, r_l = self._fk(name, base, qm)
                pot = pot - net * (p_l + r_l @ cs.DM(com))[2]
        return pot

    # -- parameters --------------------------------------------------------------------
    def nominal_parameters(self) -> np.ndarray:
        """The parameter vector p of the parameter file."""
        veh = self.params.vehicle
        p = np.zeros(NP)
        p[PARAMETER_LAYOUT["vehicle_added_mass"]] = veh.added_mass
        p[PARAMETER_LAYOUT["vehicle_damping_linear"]] = veh.damping_linear
        p[PARAMETER_LAYOUT["vehicle_damping_quadratic"]] = veh.damping_quadratic
        p[PARAMETER_LAYOUT["vehicle_displaced_volume"]] = veh.displaced_volume
        p[PARAMETER_LAYOUT["vehicle_extra_mass"]] = 0.0
        p[PARAMETER_LAYOUT["arm_added_mass_scale"]] = 1.0
        p[PARAMETER_LAYOUT["arm_drag_scale"]] = 1.0
        p[PARAMETER_LAYOUT["joint_damping"]] = self.params.arm.joint_damping
        return p


def scale_damping(p: np.ndarray, scale: float) -> np.ndarray:
    """A copy of p with every damping entry multiplied by ``scale`` (0 turns damping off)."""
    out = np.array(p, dtype=float, copy=True)
    for name in DAMPING_ENTRIES:
        out[PARAMETER_LAYOUT[name]] *= scale
    return out


@cache
def default_model() -> UVMSModel:
    """The UVMS model of the parameter file, built once per process."""
    return UVMSModel()
