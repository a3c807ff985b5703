"""The centralized controller's prediction model: the truth simulator's closed chain.

The team's prediction over one shooting interval is the simulator's own compiled period
step (``uvms_env.sim.simulator.compiled_chain``), called at the nominal parameters and
zero current, so the controller predicts for one period what the simulator computes for
it whenever the simulator accepts the period without refining it.

The sensitivities are not the step's (its exact Jacobian would be a large AD graph and
minutes of compilation per team size): one compiled call (``linearization``) gives, at
the measured state, the Jacobians of ``chain.rhs`` (over the state by forward
differences, over the inputs exactly: the rhs is affine in them), the internal (squeeze)
wrench at every node with its exact input Jacobian at the first, and the manipulability
of every robot with its gradient. Reference: docs/expert.md, "Full-information reference".

May import: numpy, casadi, ``uvms_env`` (dynamics, sim).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import casadi as cs

from uvms_env.dynamics import NP, NQ, NU
from uvms_env.dynamics.compiled import compile_function
from uvms_env.dynamics.uvms import default_model
from uvms_env.sim.chain import NG, ChainFunctions, state_size
from uvms_env.sim.simulator import chain_of_capacity


@dataclass(frozen=True)
class CentralFunctions:
    """Compiled functions of the centralized OCP for one team size and period (every
    object of a strip capacity)."""

    n: int
    nodes: int  # plan nodes whose squeeze and manipulability ``linearization`` evaluates
    chain: ChainFunctions
    step: cs.Function  # the simulator's compiled period step (see ``ChainFunctions.step``)
    linearization: cs.Function  # see ``build_linearization``


def build_linearization(chain: ChainFunctions, n: int, nodes: int) -> cs.Function:
    """(x0, a0, X, A, P, P_O, grasp, eps) -> (f0, Jx, Ju, W, Wu, m, Jm).

    x0 (nx), a0 (NU x n, normalized): where the rhs is linearized; f0 = rhs(x0, a0);
    Jx (nx x nx) forward differences of step ``eps`` (relative to max(1, |x_j|)), Ju
    (nx x NU n) exact, per normalized input (column 8 i + k: input k of robot i).
    X (nx x nodes), A (NU x n nodes): the plan's nodes and inputs; W (6n x nodes) the
    internal wrench there (stacked per robot), Wu (6n x NU n) its exact input Jacobian at
    (x0, a0); m (n x nodes) each robot's manipulability det(Jbar Jbar^T) at the nodes and
    Jm (NQ x n nodes) its gradient over the robot's q. Zero current throughout: the
    controller models none."""
    nx, nu = state_size(n), NU * n
    tau_max = cs.DM(default_model().params.limits.tau_max)
    x0, a0 = cs.MX.sym("x0", nx), cs.MX.sym("a0", NU, n)
    xs, a_s = cs.MX.sym("X", nx, nodes), cs.MX.sym("A", NU, n * nodes)
    pp, grasp = cs.MX.sym("P", NP, n), cs.MX.sym("grasp", NG, n)
    po = cs.MX.sym("P_O", chain.rhs.size1_in(4))  # the object's p_O, its shape included
    eps = cs.MX.sym("eps")
    vc = cs.MX.zeros(3)
    tau0 = cs.diag(tau_max) @ a0

    # one mapped rhs call: the base point, nx state columns, nu input columns
    steps = eps * cs.fmax(1, cs.fabs(x0))
    x_cols = cs.horzcat(x0, cs.repmat(x0, 1, nx) + cs.diag(steps), cs.repmat(x0, 1, nu))
    unit = cs.DM.eye(nu)
    tau_cols = [tau0] * (1 + nx) + [
        tau0 + cs.diag(tau_max) @ cs.reshape(unit[:, j], NU, n) for j in range(nu)
    ]
    count = 1 + nx + nu
    rhs = chain.rhs.map(count, "serial")(x_cols, cs.horzcat(*tau_cols), vc, pp, po, grasp)
    f0 = rhs[:, 0]
    jx = (rhs[:, 1 : 1 + nx] - cs.repmat(f0, 1, nx)) / cs.repmat(steps.T, nx, 1)
    ju = rhs[:, 1 + nx :] - cs.repmat(f0, 1, nu)

    squeeze = chain.internal_wrench.map(1 + nu, "serial")(
        cs.repmat(x0, 1, 1 + nu),
        cs.horzcat(tau0, *tau_cols[1 + nx :]),
        vc,
        pp,
        po,
        grasp,
    )  # 6 x n(1 + nu)
    base = cs.vec(squeeze[:, :n])
    wu = cs.horzcat(*[cs.vec(squeeze[:, n * (j + 1) : n * (j + 2)]) - base for j in range(nu)])
    tau_nodes = cs.diag(tau_max) @ a_s
    w_nodes = chain.internal_wrench.map(nodes, "serial")(xs, tau_nodes, vc, pp, po, grasp)
    w = cs.horzcat(*[cs.vec(w_nodes[:, n * k : n * (k + 1)]) for k in range(nodes)])

    q = cs.SX.sym("q", NQ)
    man = default_model().manipulability(q)
    man_fn = cs.Function("team_manipulability", [q], [man, cs.gradient(man, q)])
    q_all = cs.horzcat(*[cs.reshape(xs[: NQ * n, k], NQ, n) for k in range(nodes)])
    m, jm = man_fn.map(n * nodes, "serial")(q_all)
    return cs.Function(
        f"central_linearization_n{n}_k{nodes}",
        [x0, a0, xs, a_s, pp, po, grasp, eps],
        [f0, jx, ju, w, wu, cs.reshape(m, n, nodes), jm],
        ["x0", "a0", "X", "A", "P", "P_O", "grasp", "eps"],
        ["f0", "Jx", "Ju", "W", "Wu", "m", "Jm"],
    )


@cache
def central_functions(
    n: int, capacity: int, period: float, substeps: int, nodes: int
) -> CentralFunctions:
    """Build and compile (disk-cached) once per process and team size, for every object of
    a strip ``capacity`` (``ObjectModel.capacity``: the object is in P_O)."""
    chain, step = chain_of_capacity(n, capacity, period, substeps)
    lin = compile_function(build_linearization(chain, n, nodes))
    return CentralFunctions(n, nodes, chain, step, lin)
