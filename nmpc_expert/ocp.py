"""The optimal control problem of one robot (MODEL section 7, paper eq12) as CasADi pieces.

* ``interval``: one shooting interval, exact RK4 of the local model with ``substeps``
  substeps, and its sensitivities (Phi = dF/dx, Gamma = dF/da) chained through the RK4
  substeps from the Jacobian of f, frozen over each substep's four stages.
* ``outputs``: the cost residuals and soft-constraint values at a node, with Jacobians.
* ``qp_builder``: the condensed Gauss-Newton QP of one real-time iteration
  (``build_qp_builder``).

The Jacobian of f used for the sensitivities drops the configuration dependence of the
mass matrix and of the velocity forces (small within the speed limits); the defects are
exact, so the RTI converges to a dynamically consistent plan (docs/expert.md, "Solvers").

Soft constraints (NC = 17 per node, ``CONSTRAINT_NAMES``, normalized by their limits so one
penalty fits all) apply to x_1..x_N, never to the measured x_0. Their limits enter through
the weight vector (``lower``, ``upper``, ``scale``), built from ``NMPCSettings``. The
vehicle pitch is passive and never nears its bound under the expert, but a cloned policy
inside the safety filter tilted a vehicle past it (``safety_filter``).
Reference: docs/expert.md ("OCP", "Constraints").

May import: numpy, casadi and ``uvms_env.dynamics`` (the local model lives there:
``uvms_env.dynamics.local_model``, shared with the environment's priors).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from itertools import accumulate

import casadi as cs
import numpy as np

from uvms_env.dynamics import NQ, NU, ObjectModel
from uvms_env.dynamics.compiled import compile_function
from uvms_env.dynamics.local_model import (
    NTHETA,
    NX,
    LocalModel,
    build_local_model,
    build_steady_input,
    local_terms,
    wrap,
)
from uvms_env.dynamics.payload import object_key, object_tag
from uvms_env.dynamics.uvms import default_model

# The soft constraints of one node, in the order ``node_terms`` stacks them (rows of the
# QP per node; ``central`` selects them by name).
CONSTRAINT_NAMES = (
    *(f"vehicle_speed_{a}" for a in ("u", "v", "w", "p", "q", "r")),
    *(f"joint_speed_{k}" for k in range(1, 5)),
    *(f"joint_position_{k}" for k in range(1, 5)),
    "object_pitch",
    "vehicle_pitch",
    "manipulability",
)
NC = len(CONSTRAINT_NAMES)  # soft constraints per node (17)
# The entry of the local state x = [q; zeta] each row is (None: a function of several:
# the object's pitch through its pose, the manipulability through q).
CONSTRAINT_STATE: tuple[int | None, ...] = (*range(NQ, 2 * NQ), *range(6, NQ), None, 4, None)
# The parts of the weight vector (``weight_vector``), in order; ``steady_state`` is 1 when
# R penalizes a - a_ss, 0 when it penalizes a.
_WEIGHT_SIZES = {
    "q_x": 6,
    "q_v": 6,
    "p_x": 6,
    "r_u": NU,
    **{name: NC for name in ("slack_l1", "slack_l2", "lower", "upper", "scale")},
    "steady_state": 1,
}
_WEIGHT_ENDS = list(accumulate(_WEIGHT_SIZES.values()))
WEIGHT_LAYOUT = {
    name: slice(end - size, end)
    for (name, size), end in zip(_WEIGHT_SIZES.items(), _WEIGHT_ENDS, strict=True)
}
NW = _WEIGHT_ENDS[-1]  # size of the weight/bound vector
WEIGHT_OFFSETS = {name: part.start for name, part in WEIGHT_LAYOUT.items()}  # where each starts


def weight_vector(
    q_x: np.ndarray,
    q_v: np.ndarray,
    p_x: np.ndarray,
    r_u: np.ndarray,
    slack_l1: np.ndarray,
    slack_l2: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    scale: np.ndarray,
    steady_state: bool,
) -> np.ndarray:
    """Pack the builder's ``w`` input (``WEIGHT_LAYOUT``): diagonal weights (Qx, Qv, Px, R),
    slack penalties (L1, L2), normalized constraint bounds (lower, upper: for c / scale)
    and the row scales, and whether R penalizes a - a_ss (1) or a (0)."""
    parts = [q_x, q_v, p_x, r_u, slack_l1, slack_l2, lower, upper, scale, [float(steady_state)]]
    return np.concatenate([np.asarray(p, float).ravel() for p in parts])


@dataclass(frozen=True)
class OCPFunctions:
    """Compiled functions of the OCP for one object shape (shared by every robot)."""

    horizon: int
    model: LocalModel
    interval: cs.Function  # (x, a, theta) -> (F, Phi, Gamma)
    outputs: cs.Function  # (x, theta, xd, vd) -> (r 12, Jr 12x20, c NC, Jc NCx20)
    qp_builder: cs.Function  # see build_qp_builder
    qp_builder_graph: cs.Function  # the same, symbolic: for lane-batched builds
    object_state: cs.Function  # (x, theta) -> (x_O, v_O)
    steady_input: cs.Function  # (x, theta, v_d) -> a_ss (8)


def build_f_jac(uvms, obj: ObjectModel) -> cs.Function:
    """f(x, a) and the approximate Jacobians (see module docstring)."""
    x, a, theta = cs.SX.sym("x", NX), cs.SX.sym("a", NU), cs.SX.sym("theta", NTHETA)
    q, zeta = x[:NQ], x[NQ:]
    m_loc, r = local_terms(uvms, obj, q, zeta, theta)
    _, r_static = local_terms(uvms, obj, q, cs.DM.zeros(NQ), theta)
    b_t = cs.DM(uvms.B) @ cs.diag(cs.DM(uvms.params.limits.tau_max))
    sol = cs.solve(
        0.5 * (m_loc + m_loc.T),
        cs.horzcat(b_t @ a + r, cs.jacobian(r_static, q), cs.jacobian(r, zeta), b_t),
    )
    t_map = uvms.qdot_map(q)
    q_dot = t_map @ zeta
    f = cs.vertcat(q_dot, sol[:, 0])
    jx = cs.vertcat(cs.horzcat(cs.jacobian(q_dot, q), t_map), sol[:, 1 : 1 + 2 * NQ])
    ju = cs.vertcat(cs.DM.zeros(NQ, NU), sol[:, 1 + 2 * NQ :])
    return cs.Function("nmpc_f_jac", [x, a, theta], [f, jx, ju], {"cse": True})


def build_interval(model: LocalModel, f_jac: cs.Function, period: float, substeps: int):
    """RK4 over one interval with frozen-Jacobian sensitivities per substep. MX calls of
    the SX functions, so code generation emits f and its Jacobian once."""
    x, a, theta = cs.MX.sym("x", NX), cs.MX.sym("a", NU), cs.MX.sym("theta", NTHETA)
    dt = period / substeps
    xk, phi, gam = x, cs.MX.eye(NX), cs.MX.zeros(NX, NU)
    eye = cs.DM.eye(NX)
    for _ in range(substeps):
        k1, jx, ju = f_jac(xk, a, theta)
        k2 = model.rhs(xk + dt / 2 * k1, a, theta)
        k3 = model.rhs(xk + dt / 2 * k2, a, theta)
        k4 = model.rhs(xk + dt * k3, a, theta)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        m = dt * jx
        m2 = m @ m
        m3 = m2 @ m
        # RK4 applied to the flow linearized at the substep start: the 4th-order Taylor
        # polynomial of expm(dt J) and of its integral
        step_x = eye + m + m2 / 2 + m3 / 6 + m3 @ m / 24
        step_u = dt * (eye + m / 2 + m2 / 6 + m3 / 24) @ ju
        phi = step_x @ phi
        gam = step_x @ gam + step_u
    return cs.Function("nmpc_interval", [x, a, theta], [xk, phi, gam])


def node_terms(model: LocalModel, x, theta, xd, vd):
    """Unweighted residual [pose error (angles wrapped); twist error] and the NC
    constraint values [zeta (10); q_m (4); theta_O; theta_i; det(Jbar Jbar^T)] at one
    node (theta_i = q[4], the vehicle's ZYX pitch), in ``CONSTRAINT_NAMES`` order."""
    x_o, v_o = model.object_state(x, theta)
    r = cs.vertcat(x_o[:3] - xd[:3], wrap(x_o[3:] - xd[3:]), v_o - vd)
    c = cs.vertcat(x[NQ:], x[6:NQ], x_o[4], x[4], model.manipulability(x))
    return r, c


def build_outputs(model: LocalModel):
    """Residuals (unweighted) and constraint values with their Jacobians at one node."""
    x, theta = cs.SX.sym("x", NX), cs.SX.sym("theta", NTHETA)
    xd, vd = cs.SX.sym("xd", 6), cs.SX.sym("vd", 6)
    r, c = node_terms(model, x, theta, xd, vd)
    return cs.Function(
        "nmpc_outputs",
        [x, theta, xd, vd],
        [r, cs.jacobian(r, x), c, cs.jacobian(c, x)],
        {"cse": True},
    )


def build_qp_builder(
    interval: cs.Function, outputs: cs.Function, steady: cs.Function, horizon: int
) -> cs.Function:
    """The condensed Gauss-Newton QP of one real-time iteration around (xbar, abar).

    The state deviations are eliminated through the linearized dynamics (dx_0 = 0 is the
    measured state): dx_k = G_k da + e_k, G_k and e_k chained from (Phi, Gamma) and the
    defects F(xbar_k, abar_k) - xbar_{k+1}. What is left is a dense QP in the N * 8 input
    steps da = [da_0; ...; da_{N-1}]:

        min 0.5 da' H da + f' da   s.t.  lb <= da <= ub (saturation, hard),
                                         lbc <= C da <= ubc (soft, per node k = 1..N)

    Dense and small (docs/expert.md, "Solvers"). The soft rows are the normalized
    constraint values of x_1..x_N; their L1 + L2 slack penalties are the solver's
    business (``rti``).

    Offset-free prediction: ``d`` (NX) is added to every interval's end state, F(x_k, a_k)
    + d, the disturbance observer's estimate of what the local model misses per period
    (``policy.LocalController``); zeros give the paper's model exactly. A constant, it
    changes the defects, not the sensitivities.

    Inputs: xbar (NX x N+1), abar (NU x N), theta, xd (6 x N+1), vd (6 x N+1), w (NW),
    d (NX).
    Outputs, laid out for numpy through the buffer interface (column-major transposes):
    h (H), f, c_t (C' so that numpy reads C, 16N x 8N, row-major), lb, ub, lbc, ubc,
    g_t (G' with G = [G_1; ...; G_N], NX N x 8N), e ([e_1; ...; e_N]), a_ref (NU x N).
    """
    n = horizon
    xbar, abar = cs.MX.sym("xbar", NX, n + 1), cs.MX.sym("abar", NU, n)
    theta = cs.MX.sym("theta", NTHETA)
    xd, vd = cs.MX.sym("xd", 6, n + 1), cs.MX.sym("vd", 6, n + 1)
    w = cs.MX.sym("w", NW)
    d = cs.MX.sym("d", NX)
    use_ss = w[WEIGHT_OFFSETS["steady_state"]]

    f_next, phis, gams = interval.map(n, "serial")(xbar[:, :n], abar, cs.repmat(theta, 1, n))
    f_next = f_next + cs.repmat(d, 1, n)
    # node 0 is the measured state: neither its cost nor its constraints depend on da
    thetas = cs.repmat(theta, 1, n)
    node = outputs.map(n, "serial")(xbar[:, 1:], thetas, xd[:, 1:], vd[:, 1:])
    a_ref = use_ss * steady.map(n, "serial")(xbar[:, :n], cs.repmat(theta, 1, n), vd[:, :n])
    h_mat, f_vec, c_rows, lbc, ubc, g_rows, e_rows = _condense(
        w, xbar, abar, a_ref, (f_next, phis, gams), node
    )
    lb = cs.vec(-1 - abar)
    ub = cs.vec(1 - abar)
    dense = cs.densify
    return cs.Function(
        "nmpc_qp_builder",
        [xbar, abar, theta, xd, vd, w, d],
        [
            dense(h_mat),
            dense(f_vec),
            dense(cs.vertcat(*c_rows).T),
            dense(lb),
            dense(ub),
            dense(cs.vertcat(*lbc)),
            dense(cs.vertcat(*ubc)),
            dense(cs.vertcat(*g_rows).T),
            dense(cs.vertcat(*e_rows)),
            dense(a_ref),
        ],
        ["xbar", "abar", "theta", "xd", "vd", "w", "d"],
        ["h", "f", "c_t", "lb", "ub", "lbc", "ubc", "g_t", "e", "a_ref"],
    )


def _condense(
    w: cs.MX,
    xbar: cs.MX,
    abar: cs.MX,
    a_ref: cs.MX,
    dynamics: tuple[cs.MX, cs.MX, cs.MX],
    node: list[cs.MX],
) -> tuple[cs.MX, cs.MX, list[cs.MX], list[cs.MX], list[cs.MX], list[cs.MX], list[cs.MX]]:
    """``build_qp_builder``'s condensing (symbolic): H, f, the soft rows C with their
    bounds, and G, e of dx_k = G_k da + e_k, from the weights ``w``, the plan, the input
    reference, each interval's (F + d, Phi, Gamma) and each node's (r, Jr, c, Jc)."""
    f_next, phis, gams = dynamics
    r, jr, c, jc = node
    n = abar.shape[1]
    nz = n * NU
    part = {name: w[s] for name, s in WEIGHT_LAYOUT.items() if name != "steady_state"}
    inv_scale = 1 / part["scale"]
    r_all = cs.repmat(part["r_u"], n, 1)
    h_mat = cs.diag(2 * r_all)
    f_vec = 2 * r_all * cs.vec(abar - a_ref)
    g_k, e_k = cs.MX(NX, nz), cs.MX(NX, 1)
    c_rows, lbc, ubc, g_rows, e_rows = [], [], [], [], []
    w_run = cs.vertcat(part["q_x"], part["q_v"])
    w_end = cs.vertcat(part["p_x"], cs.MX.zeros(6))  # terminal: pose only (paper's E)
    for k in range(n):
        phi_k, gam_k = phis[:, k * NX : (k + 1) * NX], gams[:, k * NU : (k + 1) * NU]
        # dx_{k+1} = Phi_k dx_k + Gamma_k da_k + defect_k
        g_k = phi_k @ g_k + cs.horzcat(cs.MX(NX, k * NU), gam_k, cs.MX(NX, nz - (k + 1) * NU))
        e_k = phi_k @ e_k + (f_next[:, k] - xbar[:, k + 1])
        g_rows.append(g_k)
        e_rows.append(e_k)
        wr = w_run if k + 1 < n else w_end
        jr_k = jr[:, k * NX : (k + 1) * NX]
        jg = jr_k @ g_k
        h_mat += 2 * jg.T @ (wr * jg)
        f_vec += 2 * jg.T @ (wr * (r[:, k] + jr_k @ e_k))
        cj = inv_scale * jc[:, k * NX : (k + 1) * NX]
        c_rows.append(cj @ g_k)
        c_const = inv_scale * c[:, k] + cj @ e_k
        lbc.append(part["lower"] - c_const)
        ubc.append(part["upper"] - c_const)
    h_mat = 0.5 * (h_mat + h_mat.T)
    return h_mat, f_vec, c_rows, lbc, ubc, g_rows, e_rows


@cache
def ocp_functions(
    shape: str, ring_radius: float, horizon: int, period: float, substeps: int
) -> OCPFunctions:
    """Build and compile (disk-cached) the OCP functions once per process and object
    (``ring_radius``: the object's size or its key, ``uvms_env.dynamics.payload``)."""
    uvms = default_model()
    obj = ObjectModel(shape, ring_radius)
    model = build_local_model(uvms, obj)
    f_jac = build_f_jac(uvms, obj)
    interval = build_interval(model, f_jac, period, substeps)
    outputs = build_outputs(model)
    steady = build_steady_input(uvms, obj, model)
    builder = build_qp_builder(interval, outputs, steady, horizon)
    size = object_tag(object_key(shape, ring_radius))
    tag = f"{shape}_{size}_n{horizon}_h{period:g}_s{substeps}".replace(".", "p")
    graph = _renamed(builder, tag)
    compiled = compile_function(graph)
    return OCPFunctions(
        horizon=horizon,
        model=model,
        interval=interval,
        outputs=outputs,
        qp_builder=compiled,
        qp_builder_graph=graph,
        object_state=model.object_state,
        steady_input=steady,
    )


def _renamed(fn: cs.Function, tag: str) -> cs.Function:
    """The same function under a name unique per object/horizon (the cache key hashes the
    source anyway; the name only keeps the cache folder readable)."""
    args = fn.mx_in()
    return cs.Function(f"nmpc_qp_{tag}", args, fn.call(args), fn.name_in(), fn.name_out())
