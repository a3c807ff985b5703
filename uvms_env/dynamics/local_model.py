"""The local (distributed) prediction model of one UVMS and its object estimate.

Used by the NMPC expert (its prediction model) and by the environment's priors (the
steady input a_ss, ``uvms_env.robot.priors``), so both read the same functions. UVMS i
carries the share c_i of the object's dynamics (the equation: docs/expert.md, "Prediction
model").

Everything is built from the same CasADi functions as the truth simulator, at the
nominal parameters and zero current: the controller knows no more than its own model.
The grasp (l_i, R_Oi), the load share c_i and the object's nominal parameters (its
shape included: ``uvms_env.dynamics.payload``) are *inputs* of the functions, not
constants, so one compiled library serves every robot and every object of a strip
capacity.

State x = [q (10); zeta (10)]; input a (8) normalized by the saturation tau_max.
Parameter vector ``theta`` (see ``ModelParams``): [l_i (3); R_Oi (9, column-major); c_i;
p_O (``ObjectModel.parameter_count``)], ``theta_size`` numbers.

May import: numpy, casadi and ``uvms_env.dynamics`` / ``uvms_env.models``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from uvms_env.dynamics import NQ, NU, ObjectModel, UVMSModel
from uvms_env.dynamics.spatial import rot_zyx, skew, wrap_angle_sx

NX = 2 * NQ  # state of the prediction model: [q; zeta]
GRASP_THETA = 3 + 9 + 1  # theta before p_O: grasp offset, grasp rotation, load share


def theta_size(obj: ObjectModel) -> int:
    """The length of theta for robots that carry ``obj`` (or any object of its capacity)."""
    return GRASP_THETA + obj.parameter_count


def euler_zyx(rot: cs.SX) -> cs.SX:
    """ZYX Euler angles [phi, theta, psi] of a rotation matrix (symbolic; |theta| < pi/2)."""
    return cs.vertcat(
        cs.atan2(rot[2, 1], rot[2, 2]),
        -cs.asin(cs.fmin(cs.fmax(rot[2, 0], -1.0), 1.0)),
        cs.atan2(rot[1, 0], rot[0, 0]),
    )


# The cost residuals' angle wrap is the package's CasADi wrap (derivative 1 away from the
# branch cut, as the atan2 form it replaced): the expert's paper run is unchanged by it
# (1,047 periods, 0.1408 m, no violation).
wrap = wrap_angle_sx


@dataclass(frozen=True)
class ModelParams:
    """Per-robot constants of the local model, packed as the ``theta`` input."""

    grasp_offset: np.ndarray  # (3,) l_i in the object frame
    grasp_rotation: np.ndarray  # (3, 3) R_Oi
    load_share: float  # c_i
    object_parameters: np.ndarray  # nominal p_O (``ObjectModel.nominal_parameters``)

    def pack(self) -> np.ndarray:
        return np.concatenate(
            [
                np.asarray(self.grasp_offset, float),
                np.asarray(self.grasp_rotation, float).T.reshape(-1),  # column-major
                [float(self.load_share)],
                np.asarray(self.object_parameters, float),
            ]
        )


@dataclass(frozen=True)
class LocalModel:
    """Symbolic functions of the local model (SX, uncompiled).

    * ``rhs(x, a, theta) -> x_dot`` (20): the continuous dynamics above.
    * ``object_state(x, theta) -> (x_O (6), v_O (6))``: the robot's own estimate of the
      object pose (ZYX Euler) and twist ``[p_dot; omega]`` (inertial) from its kinematics.
    * ``manipulability(x) -> det(Jbar Jbar^T)`` of the actuated end-effector Jacobian.
    """

    rhs: cs.Function
    object_state: cs.Function
    manipulability: cs.Function
    tau_max: np.ndarray
    theta_size: int


def build_local_model(uvms: UVMSModel, obj: ObjectModel) -> LocalModel:
    """The local model (docs/expert.md, "Prediction model") on top of ``uvms`` and ``obj``
    (nominal, v_c = 0)."""
    x = cs.SX.sym("x", NX)
    a = cs.SX.sym("a", NU)
    theta = cs.SX.sym("theta", theta_size(obj))
    q, zeta = x[:NQ], x[NQ:]
    tau_max = np.asarray(uvms.params.limits.tau_max, float)
    x_o, v_o, *_ = _grasp_kinematics(uvms, q, zeta, theta)
    m_loc, r = local_terms(uvms, obj, q, zeta, theta)
    rhs = cs.DM(uvms.B) @ (cs.DM(tau_max) * a) + r
    zeta_dot = cs.solve(0.5 * (m_loc + m_loc.T), rhs)
    x_dot = cs.vertcat(uvms.qdot_map(q) @ zeta, zeta_dot)
    return LocalModel(
        rhs=cs.Function("local_rhs", [x, a, theta], [x_dot], {"cse": True}),
        object_state=cs.Function("local_object_state", [x, theta], [x_o, v_o], {"cse": True}),
        manipulability=cs.Function("local_manipulability", [x], [uvms.manipulability(q)]),
        tau_max=tau_max,
        theta_size=theta_size(obj),
    )


def _grasp_kinematics(uvms: UVMSModel, q, zeta, theta):
    """The object as robot i sees it through its own arm and grasp: pose x_O (ZYX Euler),
    twist v_O = A_i zeta, A_i = J_Oi^-1 J_i and Adot_i zeta."""
    offset, r_oi = theta[0:3], cs.reshape(theta[3:12], 3, 3)
    p_ee, r_ee = uvms.ee_pose(q)
    r_o = r_ee @ r_oi.T
    arm = r_o @ offset  # grasp offset in the inertial frame
    x_o = cs.vertcat(p_ee - arm, euler_zyx(r_o))
    jac = uvms.ee_jacobian(q)
    v_ee = jac @ zeta
    # J_Oi^-1 = [[I, S(R_O l_i)], [0, I]]  (J_Oi = [[I, -S(R_O l_i)], [0, I]])
    j_o_inv = cs.vertcat(
        cs.horzcat(cs.DM.eye(3), skew(arm)), cs.horzcat(cs.DM.zeros(3, 3), cs.DM.eye(3))
    )
    omega = v_ee[3:]
    # Adot_i zeta = J_Oi^-1 Jdot zeta + d/dt(J_Oi^-1) J zeta, d/dt(S(r)) = S(omega x r)
    adot_zeta = j_o_inv @ uvms.ee_jdot_zeta(q, zeta) + cs.vertcat(
        cs.cross(cs.cross(omega, arm), omega), cs.DM.zeros(3)
    )
    return x_o, j_o_inv @ v_ee, j_o_inv @ jac, adot_zeta


def local_terms(uvms, obj: ObjectModel, q, zeta, theta):
    """(M_i + c_i A_i^T M_O A_i, -h_i - c_i A_i^T (M_O Adot_i zeta + h_O)) of the local model
    (nominal parameters; the controller does not know the current)."""
    share, p_o = theta[GRASP_THETA - 1], theta[GRASP_THETA : GRASP_THETA + obj.parameter_count]
    zero3 = cs.DM.zeros(3)
    x_o, v_o, a_i, adot_zeta = _grasp_kinematics(uvms, q, zeta, theta)
    mass, bias = uvms.dynamics(q, zeta, zero3, cs.DM(uvms.nominal_parameters()))
    m_o, h_o = obj.dynamics(x_o, v_o, zero3, p_o)
    return mass + share * a_i.T @ m_o @ a_i, -bias - share * a_i.T @ (m_o @ adot_zeta + h_o)


def local_velocity_jacobian(uvms, obj: ObjectModel, q, zeta, theta):
    """d r / d zeta of ``local_terms``'s r (10 x 10): the robot's terms differentiated in
    its ten velocities, the object's bias h_O in the object's six twist directions and
    chained through v_O = A_i zeta (the same derivative, with the object's strips
    differentiated six times instead of ten)."""
    share, p_o = theta[GRASP_THETA - 1], theta[GRASP_THETA : GRASP_THETA + obj.parameter_count]
    zero3 = cs.DM.zeros(3)
    x_o, v_o, a_i, adot_zeta = _grasp_kinematics(uvms, q, zeta, theta)
    _, bias = uvms.dynamics(q, zeta, zero3, cs.DM(uvms.nominal_parameters()))
    m_o, _ = obj.dynamics(x_o, v_o, zero3, p_o)  # M_O depends on the pose only
    twist = cs.SX.sym("v_O", 6)
    _, h_o = obj.dynamics(x_o, twist, zero3, p_o)
    dh_o = cs.substitute(cs.jacobian(h_o, twist), twist, v_o)
    robot = -bias - share * a_i.T @ (m_o @ adot_zeta)
    return cs.jacobian(robot, zeta) - share * a_i.T @ dh_o @ a_i


def steady_twist(model: LocalModel, x, theta, vd):
    """The rigid motion with the object at its desired twist ``vd`` from the state ``x``:
    the robot's q with the velocities zeta_ss (vehicle twist from the rigid motion, arm
    joints still), ``build_steady_input``'s point."""
    q = x[:NQ]
    x_o, _ = model.object_state(x, theta)
    r_v = rot_zyx(q[3:6])
    lin = vd[:3] + cs.cross(vd[3:], q[:3] - x_o[:3])
    return cs.vertcat(q, r_v.T @ lin, r_v.T @ vd[3:], cs.DM.zeros(4))


def build_steady_input(uvms, obj: ObjectModel, model: LocalModel) -> cs.Function:
    """a_ss: the nominal input that keeps the robot moving rigidly with the object at the
    desired twist v_d (arm joints still, vehicle twist from the rigid motion), balancing
    drag, Coriolis and weight of the local model at zero acceleration. Roll and pitch are
    passive: their rows are left to the restoring moments. Clipped to the saturation."""
    x, theta, vd = cs.SX.sym("x", NX), cs.SX.sym("theta", theta_size(obj)), cs.SX.sym("vd", 6)
    x_ss = steady_twist(model, x, theta, vd)
    _, r = local_terms(uvms, obj, x_ss[:NQ], x_ss[NQ:], theta)
    a_ss = (cs.DM(uvms.B).T @ -r) / cs.DM(uvms.params.limits.tau_max)
    return cs.Function("nmpc_steady_input", [x, theta, vd], [cs.fmin(cs.fmax(a_ss, -1), 1)])
