"""The centralized NMPC's solver: one real-time iteration of the team's OCP per period.

``CentralRTI`` is a ``rti.RealTimeIteration`` solved by ``rti.solve_daqp``, as the
distributed robot's ``rti.RTISolver``; its own is the team's condensed Gauss-Newton QP in
the horizon x N x 8 input steps, with the cost and soft rows of ``ocp`` per robot plus
``squeeze_weight`` times the squared internal wrench (docs/expert.md, "Full-information reference").

Why numpy here and not ``ocp.build_qp_builder``: that builder is a compiled graph of one
robot's 20-state local model with a linearization per interval. The team's problem is
team-sized (132 states and 48 inputs at N = 6) and its sensitivities are frozen over the
horizon (one linearization at the measured state, ``team_model``), so G_k is block
Toeplitz in the powers Phi^j Gamma: a few matrix products, nothing to compile per team
size. The builder's concepts are each written once here, in numpy.

The squeeze's state dependence is dropped from its linearization (its input Jacobian is
exact): the cost sees what the inputs do to the squeeze, the defects keep the plan
consistent. Soft rows far from their bounds are left out of the QP and added back when the
solution violates them (``_solve_screened``: the answer is the full QP's).

May import: numpy, casadi, ``uvms_env`` and this package's ``ocp``, ``rti``,
``team_model``.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import casadi as cs
import numpy as np

from nmpc_expert.ocp import CONSTRAINT_NAMES, CONSTRAINT_STATE, NC, WEIGHT_LAYOUT
from nmpc_expert.rti import (
    FEASIBILITY_TOL,
    SOFT,
    RealTimeIteration,
    soft_penalties,
    solve_daqp,
    violation,
)
from nmpc_expert.team_model import TeamLinearization, TeamModel
from uvms_env.dynamics import NQ, NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.local_model import build_local_model, build_steady_input
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.options import state_structure

# A soft row enters the QP only while its value at the current plan is within this much
# (normalized: a fraction of its limit) of a bound; see ``CentralRTI._solve_screened``.
SCREEN_MARGIN = 0.3
# Ridge of the disturbance-cancelling input (``cancelling_input``), relative to the mean
# squared input sensitivity.
RIDGE = 1e-3
# The per-robot soft rows of a node, and the object's pitch, which the team has once.
_OBJECT_PITCH = CONSTRAINT_NAMES.index("object_pitch")
_ROBOT_ROWS = np.array([k for k in range(NC) if k != _OBJECT_PITCH])
_PITCH = 4  # the pitch in a pose (x, y, z, roll, pitch, yaw)


def team_rows(per_robot: np.ndarray, n: int) -> np.ndarray:
    """A node's team rows from the NC rows of one robot's node: robot-major, each robot's
    rows less the object pitch, then the object pitch (16 N + 1)."""
    return np.r_[np.tile(per_robot[_ROBOT_ROWS], n), per_robot[_OBJECT_PITCH]]


@cache
def _steady_function(capacity: int) -> cs.Function:
    """The expert's steady input a_ss(x, theta, v_d) of one robot (its local model's), for
    every object of a strip ``capacity`` (the object is in theta)."""
    uvms, obj = default_model(), ObjectModel.of_capacity(capacity)
    return build_steady_input(uvms, obj, build_local_model(uvms, obj))


class CentralRTI(RealTimeIteration):
    """Real-time iteration of the team's OCP: ``step(x0, a_init)`` -> (every robot's first
    input (N, 8), info), around the references ``xd``, ``vd`` set beforehand."""

    name = "central_rti"

    def __init__(
        self, model: TeamModel, theta: np.ndarray, weights: np.ndarray, squeeze_weight: float
    ) -> None:
        """``theta`` (N, NTHETA): each robot's local-model parameters (its steady input);
        ``weights``: the OCP's weight vector (``policy.controller_weights``), every
        robot's; ``squeeze_weight``: per squared N and N m of internal wrench, per interval."""
        n, hz = model.n, model.horizon
        super().__init__(hz, model.nx, (n, NU), theta, weights)
        self.model, self.robots = model, n
        self.squeeze_weight = float(squeeze_weight)
        self.disturbance = np.zeros(model.nx)  # d, added per period (written in place)
        part = {name: self.weights[s] for name, s in WEIGHT_LAYOUT.items()}
        self._steady_reference = bool(part["steady_state"][0])
        self._r_u = np.tile(part["r_u"], n)
        run = np.r_[part["q_x"], part["q_v"]]
        end = np.r_[part["p_x"], np.zeros(6)]  # terminal: pose only (paper's E)
        self._w_res = [run] * (hz - 1) + [end]
        self._row_lo, self._row_up, self._scale = (
            team_rows(part[k], n) for k in ("lower", "upper", "scale")
        )
        self._nrow = len(self._scale)  # 16 n + 1 per node
        l1, l2 = (np.tile(team_rows(part[k], n), hz) for k in ("slack_l1", "slack_l2"))
        self._soft = soft_penalties(l1, l2, hz * model.nu)
        st = state_structure(n)
        self._pose, self._twist = st["object_pose"], st["object_twist"]
        self._object = np.r_[self._pose, self._twist]  # the slices' indices
        self._velocity_rows = np.r_[st["zeta"], self._twist]
        self._select_constraints(st)
        s = model.scenario
        self._steady_fn = _steady_function(ObjectModel(s.object_shape, s.object_size).capacity)
        self._steady: dict[int, BufferCall] = {}
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.steady_inputs(np.zeros((hz, model.nx)), np.zeros((hz, 6)))  # compile it now

    def _select_constraints(self, st: dict[str, slice]) -> None:
        """Where each soft row of a node reads the team state (``ocp.CONSTRAINT_STATE``
        mapped to every robot; the object pitch from the object's pose) and, for the
        manipulability rows, each robot's q (the gradient's columns)."""
        n, q0, z0 = self.robots, st["q"].start, st["zeta"].start
        select = []
        for i in range(n):
            for j in (CONSTRAINT_STATE[k] for k in _ROBOT_ROWS):
                if j is None:  # the manipulability, a function of the robot's q
                    select.append(-1)
                else:
                    select.append(q0 + NQ * i + j if j < NQ else z0 + NQ * i + j - NQ)
        select.append(st["object_pose"].start + _PITCH)
        sel = np.array(select)
        self._direct = sel >= 0
        self._direct_state = sel[self._direct]
        self._manip = np.flatnonzero(~self._direct)
        self._manip_q = [np.arange(q0 + NQ * i, q0 + NQ * (i + 1)) for i in range(n)]

    # -- the input reference -------------------------------------------------------------
    def steady_inputs(self, xs: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """a_ss (K, N, 8) at the team states ``xs`` (K, nx) and object twists ``vd``
        (K, 6): each robot's steady input of the distributed expert (the input that keeps
        it moving rigidly with the object at the twist, carrying its load share of the
        object, at zero acceleration; ``uvms_env.dynamics.local_model``), so that R pulls
        towards the same inputs as in the expert's cost. Their sum balances the object
        (the local models add up to the team's); the squeeze they leave is the cost's."""
        n, k = self.robots, len(xs)
        q = xs[:, : NQ * n].reshape(k, n, NQ)
        zeta = xs[:, NQ * n : 2 * NQ * n].reshape(k, n, NQ)
        x_loc = np.ascontiguousarray(np.concatenate([q, zeta], axis=2).reshape(k * n, 2 * NQ))
        twist = np.ascontiguousarray(np.repeat(vd, n, axis=0))
        theta = np.ascontiguousarray(np.tile(self.theta, (k, 1)))
        call = self._steady.get(k)
        if call is None:
            # the horizon's map compiled (the virtual machine took 2.9 ms of a 25 ms
            # decision at N = 6); a single node (the first decision, a fallback) runs on
            # the virtual machine, no compilation for it
            fn = self._steady_fn.map(f"central_steady_n{n}_k{k}", "serial", k * n, [], [])
            call = self._steady[k] = BufferCall(compile_function(fn) if k == self.n else fn)
        return call(x_loc, theta, twist)[0].reshape(k, n, NU).copy()

    def cancelling_input(self, gam: np.ndarray) -> np.ndarray:
        """The input change (N*8,) whose one-period effect on the velocities (every
        robot's zeta and the object's twist) best cancels the estimated disturbance's,
        in least squares with a small ridge (directions the inputs barely reach stay
        unused)."""
        nu = self.model.nu
        if not self.disturbance.any():
            return np.zeros(nu)
        rows = self._velocity_rows
        g = gam[rows]
        ridge = RIDGE * np.trace(g.T @ g) / nu
        rhs = -g.T @ self.disturbance[rows]
        return np.linalg.solve(g.T @ g + ridge * np.eye(nu), rhs)

    # -- RealTimeIteration ---------------------------------------------------------------
    def solve_qp(self) -> tuple[np.ndarray, dict[str, Any]]:
        """Condense the team's QP around (xbar, abar) and solve it (screened): the input
        steps da (horizon * N * 8) and info; raises RuntimeError if the QP failed."""
        hz, nu = self.n, self.model.nu
        defects = self._defects()
        lin = self.model.linearize(self.xbar, self.abar)
        self._last = (lin.phi, lin.gamma, defects)
        h_mat, f_vec = self._input_cost(lin)
        c_rows, c_const = self._condense(lin, defects, h_mat, f_vec)
        h_mat = 0.5 * (h_mat + h_mat.T)
        box = (-1.0 - self.abar.reshape(-1), 1.0 - self.abar.reshape(-1))
        rows = (np.tile(self._row_lo, hz) - c_const, np.tile(self._row_up, hz) - c_const)
        da, info = self._solve_screened(h_mat, f_vec, c_rows, box, rows)
        squeeze = lin.squeeze[0] + lin.squeeze_input @ da[:nu]
        return da, {
            "status": info["status"],
            "iterations": info["iterations"],
            "rows_kept": info["rows_kept"],  # soft rows passed to the QP after screening
            "qp_solves": info["qp_solves"],  # > 1: a screened-out row was violated
            "slack_max": violation(c_rows @ da, *rows),
            "qp_violation": info["qp_violation"],
            "squeeze_rms": float(np.sqrt(np.mean(squeeze**2))),  # planned, first interval
            "defect_max": float(np.abs(defects).max()),
        }

    def state_steps(self, da: np.ndarray) -> np.ndarray:
        if self._last is None:
            raise RuntimeError("state_steps needs a solve_qp first")
        phi, gam, defects = self._last
        steps = np.empty_like(defects)
        dx = np.zeros(self.model.nx)
        for k, da_k in enumerate(da.reshape(self.n, -1)):  # through the condensed dynamics
            dx = phi @ dx + gam @ da_k + defects[k]
            steps[k] = dx
        return steps

    # -- condensing ----------------------------------------------------------------------
    def _defects(self) -> np.ndarray:
        """F(xbar_k, abar_k) + d - xbar_{k+1} of the exact period step along the plan."""
        defects = np.empty((self.n, self.model.nx))
        for k in range(self.n):
            step = self.model.step(self.xbar[k], self.abar[k]) + self.disturbance
            defects[k] = step - self.xbar[k + 1]
        return defects

    def _input_cost(self, lin: TeamLinearization) -> tuple[np.ndarray, np.ndarray]:
        """(H, f) of R around the input reference and of the squeeze of every interval
        (W_k + Wu da_k: its state dependence dropped)."""
        hz, nu = self.n, self.model.nu
        h_mat = np.diag(np.tile(2.0 * self._r_u, hz))
        a_ref = np.zeros(hz * nu)  # input_reference "zero": the paper's |a|^2_R
        if self._steady_reference:
            a_ref = self.steady_inputs(self.xbar[:hz], self.vd[:hz]).reshape(-1)
            # offset-free: the steady inputs also cancel the estimated disturbance, or R
            # would pull towards inputs that leave it uncompensated (a steady offset)
            a_ref += np.tile(self.cancelling_input(lin.gamma), hz)
        f_vec = 2.0 * np.tile(self._r_u, hz) * (self.abar.reshape(-1) - a_ref)
        if self.squeeze_weight > 0:
            wu = lin.squeeze_input  # (6n, nu)
            ww = 2.0 * self.squeeze_weight * (wu.T @ wu)
            for k in range(hz):
                blk = slice(k * nu, (k + 1) * nu)
                h_mat[blk, blk] += ww
                f_vec[blk] += 2.0 * self.squeeze_weight * (wu.T @ lin.squeeze[k])
        return h_mat, f_vec

    def _condense(
        self, lin: TeamLinearization, defects: np.ndarray, h_mat: np.ndarray, f_vec: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The state deviations eliminated, node by node: dx_k = G_k da + e_k with G_k's
        blocks the powers Phi^j Gamma (block Toeplitz: Phi, Gamma frozen over the horizon)
        and e_k = Phi e_{k-1} + defect_{k-1}; adds the tracking cost to ``h_mat`` and
        ``f_vec`` in place and returns the soft rows (C, c) of every node, C da + c."""
        hz, nx, nu, nrow = self.n, self.model.nx, self.model.nu, self._nrow
        nz = hz * nu
        powers = [lin.gamma]  # Phi^j Gamma
        for _ in range(1, hz):
            powers.append(lin.phi @ powers[-1])
        c_rows = np.empty((hz * nrow, nz))
        c_const = np.empty(hz * nrow)
        ek = np.zeros(nx)
        for k in range(1, hz + 1):
            gk = np.zeros((nx, nz))
            for j in range(k):
                gk[:, j * nu : (j + 1) * nu] = powers[k - 1 - j]
            ek = lin.phi @ ek + defects[k - 1]
            self._add_tracking(k, gk, ek, h_mat, f_vec)
            rows = slice((k - 1) * nrow, k * nrow)
            c_rows[rows], c_const[rows] = self._node_rows(k, gk, ek, lin)
        return c_rows, c_const

    def _add_tracking(
        self, k: int, gk: np.ndarray, ek: np.ndarray, h_mat: np.ndarray, f_vec: np.ndarray
    ) -> None:
        """The Gauss-Newton terms of node k's weighted object residual (pose, angles
        wrapped; twist) against the reference, added in place."""
        xk = self.xbar[k]
        pose, xd = xk[self._pose], self.xd[k]
        r = np.r_[pose[:3] - xd[:3], wrap_angle(pose[3:] - xd[3:]), xk[self._twist] - self.vd[k]]
        w = self._w_res[k - 1]
        jg = gk[self._object]
        h_mat += 2.0 * jg.T @ (w[:, None] * jg)
        f_vec += 2.0 * jg.T @ (w * (r + ek[self._object]))

    def _node_rows(
        self, k: int, gk: np.ndarray, ek: np.ndarray, lin: TeamLinearization
    ) -> tuple[np.ndarray, np.ndarray]:
        """Node k's soft rows, normalized: (C_k, c_k) with the row values C_k da + c_k."""
        n, nz, xk = self.robots, gk.shape[1], self.xbar[k]
        cr = np.empty((self._nrow, nz))
        cv = np.empty(self._nrow)
        cr[self._direct] = gk[self._direct_state]
        cv[self._direct] = xk[self._direct_state] + ek[self._direct_state]
        for i, row in enumerate(self._manip):
            q_idx = self._manip_q[i]
            grad = lin.manipulability_gradient[k * n + i]
            cr[row] = grad @ gk[q_idx]
            cv[row] = lin.manipulability[k, i] + grad @ ek[q_idx]
        return cr / self._scale[:, None], cv / self._scale

    def _solve_screened(
        self,
        h_mat: np.ndarray,
        f_vec: np.ndarray,
        c_rows: np.ndarray,
        box: tuple[np.ndarray, np.ndarray],
        rows: tuple[np.ndarray, np.ndarray],
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """The QP with only the soft rows within ``SCREEN_MARGIN`` of a bound at the
        current plan (da = 0); a left-out row that the solution violates is added and the
        QP solved again. The answer is the full QP's: a solution of the smaller QP that
        satisfies the left-out rows is feasible for the full one at the same cost (their
        slacks are zero), and the full QP's optimum cannot be lower. DAQP's cost grows
        with the rows times the variables squared, and most rows (pitch, joint angles,
        manipulability, speeds away from their limits) are far from their bounds: at
        N = 6, at one state while moving, it kept 153 of the 485 rows."""
        (lb, ub), (lo_rows, up_rows) = box, rows
        nz = len(f_vec)
        rho, w = self._soft
        keep = (lo_rows > -SCREEN_MARGIN) | (up_rows < SCREEN_MARGIN)
        for solves in range(1, 5):
            if solves == 4:  # still violating after three: the full QP, every row in
                keep[:] = True
            kept = np.flatnonzero(keep)
            sense = np.r_[np.zeros(nz), np.full(len(kept), SOFT)].astype(np.intc)
            upper, lower = np.r_[ub, up_rows[kept]], np.r_[lb, lo_rows[kept]]
            soft = (np.r_[rho[:nz], rho[nz + kept]], np.r_[w[:nz], w[nz + kept]])
            c = np.ascontiguousarray(c_rows[kept])
            _, da, _, info = solve_daqp(None, h_mat, f_vec, c, upper, lower, sense, soft)
            cda = c_rows @ da
            broken = ~keep & ((cda < lo_rows - FEASIBILITY_TOL) | (cda > up_rows + FEASIBILITY_TOL))
            if not broken.any():
                return da, {**info, "rows_kept": len(kept), "qp_solves": solves}
            keep |= broken
        raise AssertionError("unreachable: the fourth solve has every row")
