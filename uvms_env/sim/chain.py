"""The closed kinematic chain of N UVMSs rigidly grasping one object, as CasADi functions.

Each UVMS is reduced to its end-effector inertia, so the coupled system is 6x6 in
v_O_dot (the equations and their reduction: docs/model.md, "The closed chain").
State layout (flat): [q_1..q_N (10N), zeta_1..zeta_N (10N), x_O (6), v_O (6)].

One control period is one compiled function call: the RK4 substeps, then the projection
back onto the grasp manifold (Newton steps on the positions, then the velocities, each
the correction of least kinetic-energy norm; see ``manifold_projection``), and the grasp
residuals before and after it, which the simulator's error control reads. The period's
length is an input, so a period that must be refined is integrated as two halves by the
same compiled function. Every solve is an SX expression (no data-dependent branch), so
the same generated C can also run one environment per SIMD lane or GPU thread. The object
is its parameters P_O (its shape included: ``uvms_env.dynamics.payload``), so one library
serves every object of a strip capacity; the per-robot functions are built once per
model, so that the generated code holds each once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import casadi as cs

from uvms_env.dynamics import NP, NQ, NU, ObjectModel, UVMSModel
from uvms_env.dynamics.payload import grasp_jacobian, grasp_jdot_v
from uvms_env.dynamics.spatial import euler_rate_matrix, rot_zyx, rotation_error
from uvms_env.dynamics.spd import spd_inverse, spd_solve

NG = 12  # grasp description per robot: offset l_i (3) and R_Oi (9, column-major)
# Newton steps of the position projection. The simulator refines a period whose drift
# exceeds 1e-5 before projecting, and Newton squares the error: 1e-5 -> ~1e-10, far
# inside the promised 1e-6, which the simulator checks after every period anyway.
PROJECTION_ITERATIONS = 1


def state_size(n: int) -> int:
    return 20 * n + 12


@dataclass(frozen=True)
class ChainFunctions:
    """Symbolic closed-chain functions for N robots (uncompiled)."""

    n: int
    rhs: cs.Function  # (x, tau, v_c, P, P_O, grasp) -> x_dot
    # (x, tau, v_c, P, P_O, grasp, h) -> (x after a period of length h, projected;
    # drift 12xN: pose and twist grasp residuals before the projection; error 6xN: pose
    # residual after it)
    step: cs.Function
    wrenches: cs.Function  # (x, tau, v_c, P, P_O, grasp) -> lambda (6xN)
    internal_wrench: cs.Function  # same inputs -> the squeeze (6xN), cancels on the object
    grasp_error: (
        cs.Function
    )  # (x, grasp) -> (position error 3xN, rotation error 3xN, twist error 6xN)
    projection: cs.Function  # (x, P, P_O, grasp) -> x on the grasp manifold


@cache
def grasp_residual(uvms: UVMSModel) -> cs.Function:
    """Grasp pose error e_i (position, rotation; inertial frame) and twist error e_dot_i."""
    q, zeta, grasp = cs.SX.sym("q", NQ), cs.SX.sym("zeta", NQ), cs.SX.sym("grasp", NG)
    x_o, v_o = cs.SX.sym("x_O", 6), cs.SX.sym("v_O", 6)
    p_ee, r_ee = uvms.ee_pose(q)
    offset, r_oi = grasp[:3], cs.reshape(grasp[3:], 3, 3)
    r_o = rot_zyx(x_o[3:])
    err = cs.vertcat(p_ee - (x_o[:3] + r_o @ offset), rotation_error(r_ee, r_o @ r_oi))
    err_dot = uvms.ee_jacobian(q) @ zeta - grasp_jacobian(r_o, offset) @ v_o
    return cs.Function("grasp_residual", [q, zeta, grasp, x_o, v_o], [err, err_dot])


def robot_stage(uvms: UVMSModel, stabilization: float) -> cs.Function:
    """Per-robot reduction (docs/model.md, "The closed chain"), one SX function for every robot."""
    q, zeta, tau = cs.SX.sym("q", NQ), cs.SX.sym("zeta", NQ), cs.SX.sym("tau", NU)
    v_c, p, grasp = cs.SX.sym("v_c", 3), cs.SX.sym("p", NP), cs.SX.sym("grasp", NG)
    x_o, v_o = cs.SX.sym("x_O", 6), cs.SX.sym("v_O", 6)
    mass, bias = uvms.dynamics(q, zeta, v_c, p)
    jac = uvms.ee_jacobian(q)
    jdot = uvms.ee_jdot_zeta(q, zeta)
    offset = grasp[:3]
    r_o = rot_zyx(x_o[3:])
    j_o = grasp_jacobian(r_o, offset)
    err, err_dot = grasp_residual(uvms)(q, zeta, grasp, x_o, v_o)
    w = stabilization
    c = grasp_jdot_v(r_o, offset, v_o) - 2 * w * err_dot - w * w * err

    sol = spd_solve(mass, cs.horzcat(cs.DM(uvms.B) @ tau - bias, jac.T))
    acc_free, minv_jt = sol[:, 0], sol[:, 1:]
    lam = spd_inverse(jac @ minv_jt)  # operational-space inertia Lambda_i (6x6, SPD)
    a_free = jac @ acc_free + jdot
    lam_a = lam @ (a_free - c)
    lam_jo = lam @ j_o
    return cs.Function(
        "robot_stage",
        [q, zeta, tau, v_c, p, grasp, x_o, v_o],
        [
            j_o.T @ lam_jo,  # K_i
            j_o.T @ lam_a,  # r_i
            acc_free - minv_jt @ lam_a,  # zeta_dot_i = this + G_i v_O_dot
            minv_jt @ lam_jo,  # G_i
            uvms.qdot_map(q) @ zeta,  # q_dot_i
            lam_a,  # lambda_i = this - (Lambda_i J_Oi) v_O_dot
            lam_jo,
        ],
        {"cse": True},
    )


@cache
def _solve6() -> cs.Function:
    """6x6 solve with the object's coupled inertia (SPD) as SX: expanded, branch-free (an MX
    ``cs.solve`` becomes CasADi's QR linear solver, whose pivoting branches have no meaning
    per SIMD lane)."""
    a, b = cs.SX.sym("A", 6, 6), cs.SX.sym("b", 6)
    return cs.Function("solve6", [a, b], [spd_solve(a, b)], {"cse": True})


def robot_metric(uvms: UVMSModel) -> cs.Function:
    """Per-robot blocks of the least-kinetic-energy correction onto the grasp manifold.

    With W = blkdiag(M_1..M_N, M_O), the smallest W-norm correction (delta_i, delta_O)
    that cancels the linearized residuals, J_i delta_i - J_Oi delta_O = -e_i, reduces to
    the same 6x6 object system as the dynamics:
        (M_O + sum_i J_Oi^T Lambda_i J_Oi) delta_O = sum_i J_Oi^T Lambda_i e_i
        delta_i = -M_i^-1 J_i^T Lambda_i e_i + (M_i^-1 J_i^T Lambda_i J_Oi) delta_O
    Outputs: J_Oi^T Lambda_i J_Oi, J_Oi^T Lambda_i, M_i^-1 J_i^T Lambda_i, and the last
    times J_Oi. The metric's inverse mass matrix M_i^-1 is an input: the projection
    evaluates it once, at the integrated state, and keeps it through its Newton steps
    (any fixed SPD metric gives a valid projection; only the Jacobians must follow q).
    """
    q, minv = cs.SX.sym("q", NQ), cs.SX.sym("Minv", NQ, NQ)
    grasp, x_o = cs.SX.sym("grasp", NG), cs.SX.sym("x_O", 6)
    jac = uvms.ee_jacobian(q)
    minv_jt = minv @ jac.T
    lam = spd_inverse(jac @ minv_jt)
    j_o = grasp_jacobian(rot_zyx(x_o[3:]), grasp[:3])
    w = j_o.T @ lam
    pp = minv_jt @ lam
    return cs.Function(
        "robot_metric", [q, minv, grasp, x_o], [w @ j_o, w, pp, pp @ j_o], {"cse": True}
    )


def manifold_projection(
    n: int, uvms: UVMSModel, obj: ObjectModel, iterations: int = PROJECTION_ITERATIONS
) -> cs.Function:
    """(x, P, P_O, grasp) -> x on the grasp manifold: ``iterations`` Newton steps on the
    positions, then one exact step on the velocities (linear), each the correction of
    least kinetic-energy norm (``robot_metric``). The per-robot work is in SX functions
    called by name (an inlined projection tripled the generated code, and compile times
    with it, for a few percent of speed)."""
    x = cs.MX.sym("x", state_size(n))
    pp, grasp = cs.MX.sym("P", NP, n), cs.MX.sym("grasp", NG, n)
    po = cs.MX.sym("P_O", obj.parameter_count)
    metric, residual, solve6 = robot_metric(uvms), grasp_residual(uvms), _solve6()
    q = [x[NQ * i : NQ * (i + 1)] for i in range(n)]
    zeta = [x[NQ * (n + i) : NQ * (n + i + 1)] for i in range(n)]
    x_o, v_o = x[2 * NQ * n : 2 * NQ * n + 6], x[2 * NQ * n + 6 :]
    zero3 = cs.MX.zeros(3)
    qs, ps = cs.SX.sym("q", NQ), cs.SX.sym("p", NP)
    mass_inverse = cs.Function(
        "uvms_mass_inverse", [qs, ps], [spd_inverse(uvms.mass_matrix(qs, ps))], {"cse": True}
    )
    masses = [mass_inverse(q[i], pp[:, i]) for i in range(n)]
    m_o = obj.dynamics(x_o, v_o, zero3, po)[0]

    def correction(blocks, residuals):
        k_sum = m_o + sum(b[0] for b in blocks)
        d_o = solve6(k_sum, sum(b[1] @ e for b, e in zip(blocks, residuals, strict=True)))
        d = [-b[2] @ e + b[3] @ d_o for b, e in zip(blocks, residuals, strict=True)]
        return d, d_o

    for _ in range(iterations):
        blocks = [metric(q[i], masses[i], grasp[:, i], x_o) for i in range(n)]
        errs = [residual(q[i], zeta[i], grasp[:, i], x_o, v_o)[0] for i in range(n)]
        d, d_o = correction(blocks, errs)
        q = [q[i] + uvms.qdot_matrix(q[i]) @ d[i] for i in range(n)]
        rate = euler_rate_matrix(x_o[3:]) @ rot_zyx(x_o[3:]).T
        x_o = cs.vertcat(x_o[:3] + d_o[:3], x_o[3:] + rate @ d_o[3:])
    blocks = [metric(q[i], masses[i], grasp[:, i], x_o) for i in range(n)]
    errs = [residual(q[i], zeta[i], grasp[:, i], x_o, v_o)[1] for i in range(n)]
    d, d_o = correction(blocks, errs)  # linear in the velocities: one step is exact
    zeta = [zeta[i] + d[i] for i in range(n)]
    out = cs.vertcat(*q, *zeta, x_o, v_o + d_o)
    return cs.Function(f"grasp_projection_n{n}", [x, pp, po, grasp], [out], {"cse": True})


def _rk4(rhs: Callable[[cs.MX], cs.MX], x: cs.MX, h: cs.MX, substeps: int) -> cs.MX:
    """``substeps`` classical Runge-Kutta steps of ``x' = rhs(x)`` over ``h``."""
    dt = h / substeps
    xk = x
    for _ in range(substeps):
        k1 = rhs(xk)
        k2 = rhs(xk + dt / 2 * k1)
        k3 = rhs(xk + dt / 2 * k2)
        k4 = rhs(xk + dt * k3)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return xk


def _squeeze(lam: cs.MX, x_o: cs.MX, grasp: cs.MX, n: int, solve6: cs.Function) -> cs.MX:
    """The internal wrench: the grasp wrenches ``lam`` (6, n) minus their projection on
    the range of A^T, A = G^T = [J_O1^T .. J_ON^T] (full row rank: every J_Oi is
    invertible), so pinv(A) = A^T (A A^T)^-1 and A A^T = sum_i J_Oi^T J_Oi: one 6x6 solve
    instead of a pseudo-inverse."""
    r_o = rot_zyx(x_o[3:])
    j_o = [grasp_jacobian(r_o, grasp[:3, i]) for i in range(n)]
    y = solve6(sum(j.T @ j for j in j_o), sum(j.T @ lam[:, i] for i, j in enumerate(j_o)))
    return cs.horzcat(*[lam[:, i] - j @ y for i, j in enumerate(j_o)])


def build_chain(
    n: int,
    uvms: UVMSModel,
    obj: ObjectModel,
    period: float,
    substeps: int,
    stabilization: float,
) -> ChainFunctions:
    """Closed-chain functions for ``n`` robots; ``step`` integrates one control period."""
    stage = robot_stage(uvms, stabilization).map(n, "serial")
    x = cs.MX.sym("x", state_size(n))
    tau = cs.MX.sym("tau", NU, n)
    v_c = cs.MX.sym("v_c", 3)
    pp = cs.MX.sym("P", NP, n)
    po = cs.MX.sym("P_O", obj.parameter_count)
    grasp = cs.MX.sym("grasp", NG, n)
    args = [x, tau, v_c, pp, po, grasp]
    solve6 = _solve6()

    def unpack(xx: cs.MX) -> tuple[cs.MX, cs.MX, cs.MX, cs.MX]:
        q = cs.reshape(xx[: NQ * n], NQ, n)
        zeta = cs.reshape(xx[NQ * n : 2 * NQ * n], NQ, n)
        return q, zeta, xx[2 * NQ * n : 2 * NQ * n + 6], xx[2 * NQ * n + 6 :]

    def solve_stage(xx: cs.MX) -> tuple[list[cs.MX], cs.MX]:
        q, zeta, x_o, v_o = unpack(xx)
        outs = stage(
            q,
            zeta,
            tau,
            cs.repmat(v_c, 1, n),
            pp,
            grasp,
            cs.repmat(x_o, 1, n),
            cs.repmat(v_o, 1, n),
        )
        k_blocks, r = outs[0], outs[1]
        m_o, h_o = obj.dynamics(x_o, v_o, v_c, po)
        k_sum = m_o + k_blocks @ cs.repmat(cs.DM.eye(6), n, 1)
        v_o_dot = solve6(k_sum, cs.sum2(r) - h_o)
        return outs, v_o_dot

    def rhs_expr(xx: cs.MX) -> cs.MX:
        outs, v_o_dot = solve_stage(xx)
        z_part, g_blocks, q_dot = outs[2], outs[3], outs[4]
        _, _, x_o, v_o = unpack(xx)
        g_list = cs.horzsplit(g_blocks, list(range(0, 6 * n + 1, 6)))
        zeta_dot = cs.horzcat(*[z_part[:, i] + g_list[i] @ v_o_dot for i in range(n)])
        return cs.vertcat(cs.vec(q_dot), cs.vec(zeta_dot), obj.pose_rate(x_o, v_o), v_o_dot)

    rhs = cs.Function("chain_rhs", args, [rhs_expr(x)])
    h = cs.MX.sym("h")
    xk = _rk4(rhs_expr, x, h, substeps)
    residual = grasp_residual(uvms).map(n, "serial")

    def residuals(xx: cs.MX) -> tuple[cs.MX, cs.MX]:
        q, zeta, x_o, v_o = unpack(xx)
        return residual(q, zeta, grasp, cs.repmat(x_o, 1, n), cs.repmat(v_o, 1, n))

    drift = cs.vertcat(*residuals(xk))
    projection = manifold_projection(n, uvms, obj)
    x_end = projection(xk, pp, po, grasp)
    # Residuals before and after the projection come out of the same call: the simulator
    # decides from them whether the period was integrated accurately, without another
    # evaluation.
    step = cs.Function(f"chain_step_n{n}", [*args, h], [x_end, drift, residuals(x_end)[0]])

    outs, v_o_dot = solve_stage(x)
    lam = outs[5] - cs.horzcat(
        *[blk @ v_o_dot for blk in cs.horzsplit(outs[6], list(range(0, 6 * n + 1, 6)))]
    )
    wrenches = cs.Function("chain_wrenches", args, [lam])
    _, _, x_o, _ = unpack(x)
    internal = _squeeze(lam, x_o, grasp, n, solve6)
    internal_wrench = cs.Function(f"chain_internal_wrench_n{n}", args, [internal])
    q, zeta, x_o, v_o = unpack(x)
    err, err_dot = residual(q, zeta, grasp, cs.repmat(x_o, 1, n), cs.repmat(v_o, 1, n))
    grasp_error = cs.Function("chain_grasp_error", [x, grasp], [err[:3, :], err[3:, :], err_dot])
    return ChainFunctions(n, rhs, step, wrenches, internal_wrench, grasp_error, projection)
