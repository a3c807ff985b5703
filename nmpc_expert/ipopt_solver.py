"""The reference solver: the same OCP solved to convergence by IPOPT (``--solver ipopt``).

Exactly the problem the real-time iteration linearizes (``ocp``): multiple shooting with
exact RK4 of the local model (same substeps), the same weights, soft constraints with
the same L1 + L2 slack penalties, and the same input reference a_ref (taken, like the
RTI's, at the shifted warm start). Derivatives are exact (CasADi AD, virtual machine);
the Hessian is IPOPT's limited-memory approximation, since the exact Hessian of the RK4
constraints is a graph of ~10^7 operations. Slow (a second or so per decision): it is the
yardstick for the fast solver, not a real-time controller.

May import: numpy, casadi and this package's ``ocp``/``rti``/``local_model``/``settings``.
"""

from __future__ import annotations

from typing import Any

import casadi as cs
import numpy as np

from nmpc_expert.ocp import NC, NW, WEIGHT_OFFSETS, OCPFunctions, node_terms
from nmpc_expert.rti import RealTimeIteration
from nmpc_expert.settings import NMPCSettings
from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.dynamics.local_model import NX


class IpoptSolver(RealTimeIteration):
    """Converged multiple-shooting NMPC. Same interface as ``RTISolver``, whose plan,
    shift (here with the slacks ``sbar``) and fallback it shares; ``step`` solves to
    convergence instead of iterating once."""

    name = "ipopt"

    def __init__(
        self, funcs: OCPFunctions, theta: np.ndarray, weights: np.ndarray, settings: NMPCSettings
    ) -> None:
        n = funcs.horizon
        super().__init__(n, NX, (NU,), theta, weights)
        self.funcs = funcs
        self._build = BufferCall(funcs.qp_builder)
        self._no_disturbance = np.zeros(NX)  # the paper's model (no disturbance observer)
        self.sbar = np.zeros((n, NC))
        self._solver, self._lbg, self._ubg = self._make(settings)

    def _make(self, settings: NMPCSettings):
        n, model = self.n, self.funcs.model
        x = cs.MX.sym("X", NX, n + 1)
        a = cs.MX.sym("A", NU, n)
        s = cs.MX.sym("S", NC, n)
        p_x0, p_theta = cs.MX.sym("x0", NX), cs.MX.sym("theta", model.theta_size)
        p_xd, p_vd = cs.MX.sym("xd", 6, n + 1), cs.MX.sym("vd", 6, n + 1)
        p_aref, p_w = cs.MX.sym("aref", NU, n), cs.MX.sym("w", NW)
        o = 18 + NU
        q_x, q_v, p_x, r_u = p_w[0:6], p_w[6:12], p_w[12:18], p_w[18:o]
        l1, l2, scale = (p_w[o + k * NC : o + (k + 1) * NC] for k in (0, 1, 4))

        xs, ts = cs.MX.sym("x", NX), cs.MX.sym("t", model.theta_size)
        av = cs.MX.sym("a", NU)
        dt = settings.period / settings.substeps
        xk = xs
        for _ in range(settings.substeps):
            k1 = model.rhs(xk, av, ts)
            k2 = model.rhs(xk + dt / 2 * k1, av, ts)
            k3 = model.rhs(xk + dt / 2 * k2, av, ts)
            k4 = model.rhs(xk + dt * k3, av, ts)
            xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        step = cs.Function("rk4", [xs, av, ts], [xk])
        xn = cs.MX.sym("xn", NX)
        xdn, vdn = cs.MX.sym("xdn", 6), cs.MX.sym("vdn", 6)
        r_n, c_n = node_terms(model, xn, ts, xdn, vdn)
        node = cs.Function("node", [xn, ts, xdn, vdn], [r_n, c_n])

        cost = 0
        g, lbg, ubg = [x[:, 0] - p_x0], [np.zeros(NX)], [np.zeros(NX)]
        for k in range(n + 1):
            r, _ = node(x[:, k], p_theta, p_xd[:, k], p_vd[:, k])
            if 0 < k < n:
                cost += cs.sumsqr(cs.sqrt(cs.vertcat(q_x, q_v)) * r)
            elif k == n:
                cost += cs.sumsqr(cs.sqrt(p_x) * r[:6])
            if k == n:
                break
            cost += cs.sumsqr(cs.sqrt(r_u) * (a[:, k] - p_aref[:, k]))
            cost += cs.dot(l1, s[:, k]) + cs.sumsqr(cs.sqrt(l2) * s[:, k])
            g.append(step(x[:, k], a[:, k], p_theta) - x[:, k + 1])
            lbg.append(np.zeros(NX))
            ubg.append(np.zeros(NX))
            _, c_next = node(x[:, k + 1], p_theta, p_xd[:, k + 1], p_vd[:, k + 1])
            cn = c_next / scale
            g += [cn + s[:, k], cn - s[:, k]]  # lower/upper bounds set per solve
            lbg += [np.full(NC, np.nan), -np.inf * np.ones(NC)]
            ubg += [np.inf * np.ones(NC), np.full(NC, np.nan)]
        w = cs.vertcat(cs.vec(x), cs.vec(a), cs.vec(s))
        p = cs.vertcat(p_x0, p_theta, cs.vec(p_xd), cs.vec(p_vd), cs.vec(p_aref), p_w)
        opts: dict[str, Any] = {
            "ipopt": {
                "print_level": 0,
                "tol": 1e-8,
                "acceptable_tol": 1e-6,
                "max_iter": 300,
                "hessian_approximation": "limited-memory",
                "warm_start_init_point": "yes",
                "mu_init": 1e-3,
            },
            "print_time": False,
            "error_on_fail": False,
        }
        solver = cs.nlpsol(
            "nmpc_ipopt", "ipopt", {"x": w, "p": p, "f": cost, "g": cs.vertcat(*g)}, opts
        )
        return solver, np.concatenate(lbg), np.concatenate(ubg)

    def shift(self, x0: np.ndarray, a_init: np.ndarray | None) -> None:
        if self.has_plan:
            self.sbar[:-1] = self.sbar[1:].copy()
        else:
            self.sbar[:] = 0.0
        super().shift(x0, a_init)

    def step(self, x0: np.ndarray, a_init: np.ndarray | None) -> tuple[np.ndarray, dict[str, Any]]:
        self.shift(x0, a_init)
        a_ref = self._build(
            self.xbar, self.abar, self.theta, self.xd, self.vd, self.weights, self._no_disturbance
        )[9]
        n = self.n
        w0 = np.concatenate([self.xbar.ravel(), self.abar.ravel(), self.sbar.ravel()])
        lbx = np.concatenate([-np.inf * np.ones(NX * (n + 1)), -np.ones(NU * n), np.zeros(NC * n)])
        ubx = np.concatenate(
            [np.inf * np.ones(NX * (n + 1)), np.ones(NU * n), np.inf * np.ones(NC * n)]
        )
        p = np.concatenate(
            [x0, self.theta, self.xd.ravel(), self.vd.ravel(), a_ref.ravel(), self.weights]
        )
        lo, up = WEIGHT_OFFSETS["lower"], WEIGHT_OFFSETS["upper"]
        lower, upper = self.weights[lo : lo + NC], self.weights[up : up + NC]
        lbg, ubg = self._lbg.copy(), self._ubg.copy()
        lbg[np.isnan(lbg)] = np.tile(lower, n)
        ubg[np.isnan(ubg)] = np.tile(upper, n)
        sol = self._solver(x0=w0, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        st = self._solver.stats()
        w = sol["x"].full().ravel()
        if not np.all(np.isfinite(w)):
            raise RuntimeError("IPOPT returned a non-finite solution")
        ok = st.get("success", False) or st.get("return_status") == "Solved_To_Acceptable_Level"
        if not ok:
            raise RuntimeError(f"IPOPT failed: {st.get('return_status')}")
        nx = NX * (n + 1)
        self.xbar[:] = w[:nx].reshape(n + 1, NX)
        self.abar[:] = w[nx : nx + NU * n].reshape(n, NU)
        self.sbar[:] = w[nx + NU * n :].reshape(n, NC)
        self.has_plan = True
        info = {
            "status": str(st.get("return_status")),
            "iterations": int(st.get("iter_count", -1)),
            "objective": float(sol["f"]),
            "slack_max": float(self.sbar.max()),
        }
        return self.abar[0].copy(), info
