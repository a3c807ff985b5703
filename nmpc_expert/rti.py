"""The fast default solver: a real-time iteration (one Gauss-Newton SQP step per sample).

Per decision: shift the previous plan (warm start), build the QP around it with one
compiled call (``ocp.qp_builder``: RK4 defects and sensitivities, residuals, soft
constraints), solve it with HPIPM (a Riccati-based interior point that exploits the
stage structure), check the solution yourself (finite, status, primal feasibility), take
the full step and apply the first input.

A failed QP never stalls the loop: the controller applies the shifted previous plan (or,
with no plan yet, the nominal holding input) and counts a fallback.

May import: numpy, casadi, ``uvms_env`` and this package's ``ocp``/``settings``.
"""

from __future__ import annotations

import time
from typing import Any

import casadi as cs
import numpy as np
from scipy.sparse import csc_matrix

from nmpc_expert.local_model import NX
from nmpc_expert.ocp import NC, OCPFunctions
from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import BufferCall

# Primal feasibility accepted from the QP solver (normalized units; the HPIPM default
# tolerance is 1e-8, anything above 1e-5 means it stopped early or diverged).
FEASIBILITY_TOL = 1e-5


_SOLVERS: dict[int, cs.Function] = {}


def qp_solver(funcs: OCPFunctions) -> cs.Function:
    """One HPIPM instance per QP structure and process (creating it costs milliseconds;
    robots of one process share it: it keeps no state between calls, warm_start = 0)."""
    key = id(funcs)
    if key not in _SOLVERS:
        _SOLVERS[key] = _make_qp_solver(funcs.h_sparsity, funcs.a_sparsity, funcs.horizon)
    return _SOLVERS[key]


def _make_qp_solver(h_sp: cs.Sparsity, a_sp: cs.Sparsity, n: int) -> cs.Function:
    opts: dict[str, Any] = {
        "N": n,
        "nx": [NX] * (n + 1),
        "nu": [NU + NC] * n + [0],
        "ng": [2 * NC] * n + [0],
        "error_on_fail": False,
        "print_problem": False,
        "hpipm": {"iter_max": 30, "warm_start": 0, "mode": "speed"},
    }
    return cs.conic("nmpc_qp", "hpipm", {"h": h_sp, "a": a_sp}, opts)


class RTISolver:
    """Real-time iteration for one robot. ``solve(x0, xd, vd)`` -> first input (8,)."""

    name = "rti"

    def __init__(self, funcs: OCPFunctions, theta: np.ndarray, weights: np.ndarray) -> None:
        self.funcs = funcs
        n = funcs.horizon
        self.n = n
        self._build = BufferCall(funcs.qp_builder, sparse=True)
        self._qp = qp_solver(funcs)
        sp = funcs.a_sparsity
        col, row = sp.get_ccs()
        self._a_csc = csc_matrix((np.zeros(sp.nnz()), row, col), shape=sp.shape)
        self.theta = np.ascontiguousarray(theta, dtype=float)
        self.weights = np.ascontiguousarray(weights, dtype=float)
        self.xbar = np.zeros((n + 1, NX))  # row k = node k (CasADi column-major NX x N+1)
        self.abar = np.zeros((n, NU))
        self.xd = np.zeros((n + 1, 6))
        self.vd = np.zeros((n + 1, 6))
        self.has_plan = False
        self.stats: dict[str, Any] = {}
        self._nv = funcs.h_sparsity.size1()

    def reset(self) -> None:
        self.has_plan = False
        self.xbar[:] = 0.0
        self.abar[:] = 0.0

    def shift(self, x0: np.ndarray, a_init: np.ndarray) -> None:
        """Warm start: the previous plan moved one interval forward (last node repeated)."""
        if self.has_plan:
            self.xbar[:-1] = self.xbar[1:].copy()
            self.abar[:-1] = self.abar[1:].copy()
        else:
            self.xbar[:] = x0
            self.abar[:] = a_init
        self.xbar[0] = x0

    def solve_qp(self) -> tuple[np.ndarray, dict[str, Any]]:
        """Build and solve the QP around (xbar, abar); raise RuntimeError if it failed."""
        h, g, a, lba, uba, lbx, ubx, _ = self._build(
            self.xbar, self.abar, self.theta, self.xd, self.vd, self.weights
        )
        sol = self._qp(
            h=cs.DM(self.funcs.h_sparsity, h),
            g=g,
            a=cs.DM(self.funcs.a_sparsity, a),
            lba=lba,
            uba=uba,
            lbx=lbx,
            ubx=ubx,
        )
        st = self._qp.stats()
        dw = sol["x"].full().ravel()
        if not np.all(np.isfinite(dw)):
            raise RuntimeError("QP solution is not finite")
        # own feasibility check (a solver may stop early and still return numbers)
        self._a_csc.data[:] = a
        ax = self._a_csc @ dw
        viol = max(
            float(np.max(lba - ax, initial=0.0)),
            float(np.max(ax - uba, initial=0.0)),
            float(np.max(lbx - dw, initial=0.0)),
            float(np.max(dw - ubx, initial=0.0)),
        )
        info = {
            "status": str(st.get("unified_return_status", st.get("return_status", ""))),
            "iterations": int(st.get("iter_count", -1)),  # QP (interior-point) iterations
            "qp_violation": viol,
        }
        if viol > FEASIBILITY_TOL:
            raise RuntimeError(f"QP solution infeasible by {viol:.2e}")
        return dw, info

    def step(self, x0: np.ndarray, a_init: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """One real-time iteration from the measured state x0; returns (a_0, info)."""
        self.shift(x0, a_init)
        dw, info = self.solve_qp()
        n, stage = self.n, NX + NU + NC
        for k in range(n):
            self.xbar[k] += dw[k * stage : k * stage + NX]
            self.abar[k] += dw[k * stage + NX : k * stage + NX + NU]
        self.xbar[n] += dw[n * stage :]
        np.clip(self.abar, -1.0, 1.0, out=self.abar)
        self.has_plan = True
        info["slack_max"] = float(
            max(np.max(dw[k * stage + NX + NU : (k + 1) * stage]) for k in range(n))
        )
        return self.abar[0].copy(), info

    def fallback(self, x0: np.ndarray, a_hold: np.ndarray) -> np.ndarray:
        """The shifted previous plan's first input (already shifted by ``step``), or the
        holding input when there is no plan."""
        if self.has_plan:
            return self.abar[0].copy()
        return np.clip(a_hold, -1.0, 1.0)


def timed(fn, *args) -> tuple[Any, float]:
    t = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t) * 1e3
