"""The centralized NMPC: one optimal control problem over the whole team's inputs.

The full-information bound of the ladder (ARCHITECTURE: "a team policy"): a team policy
(``uvms_env.team_policy``) that reads the global state (``env.state()``: every robot's
q and zeta, the object's pose and twist, the team's waypoint) and decides the N x 8
normalized inputs of every robot at once. What it has that no robot of the distributed
expert has: the exact coupled team-and-object model and the internal (squeeze) wrench.

    team = CentralNMPC(scenario)        # or make_central_policy()(scenario)
    team.reset()
    actions = team.act(env.state())     # (N, 8) in [-1, 1]
    team.stats                          # solve_time_ms, status, fallbacks, squeeze_rms, ...

The OCP is the distributed expert's (``ocp``, paper eq12) over the team:

* prediction: the simulator's own period step at the nominal parameters and zero
  current (``central_model``): the model equals the simulator's team dynamics;
* cost: the object's pose and twist tracking of the navigation reference (the same
  ``HorizonReference`` from the same ``task_navigator``, the same weights Qx, Qv, Px and
  R on the normalized inputs, R around each robot's steady input a_ss, as the expert's
  ``input_reference = "steady_state"``), plus
  ``squeeze_weight`` times the squared internal wrench of every interval (N and N m);
* constraints: the expert's soft constraints per robot and node (``constraint_bounds``:
  vehicle speeds, joint speeds and positions, vehicle pitch, manipulability, and the
  object's pitch once per node) with the expert's exact L1 + L2 slack penalties; the
  input saturation as hard bounds.

Solver: one real-time iteration per period, as ``rti``: shift the previous plan, build
the condensed Gauss-Newton QP around it, solve it with DAQP (``rti.solve_daqp``), take
the full step. The condensing is ``ocp.build_qp_builder``'s (dx_k = G_k da + e_k from
the sensitivities and the exact defects) written in numpy: the builder's compiled graph
is the local model's; the team's sensitivities are frozen over the horizon (one
linearization at the measured state, discretized by the simulator's own RK4 substeps:
see ``central_model`` for why), so G_k is block Toeplitz, a few matrix products. The
squeeze's state dependence is dropped from its linearization (its input Jacobian is
exact): the cost sees what the inputs do to the squeeze, the defects keep the plan
consistent. Soft rows far from their bounds are left out of the QP and added back
when the solution violates them (``_solve_screened``: the answer is the full QP's).
A failed solve never raises: the previous plan shifted (or, with none, the robots'
steady inputs at rest) is applied and counted as a fallback.

Not modelled: the current, parameter mismatch and sensor noise of a scenario. The
expert's goal integral (``reference.GoalIntegral``) removes what is left of their
steady offset at the goal (R pulls towards the nominal steady inputs). What they
do is estimated instead, as offset-free MPC does: the measured state minus the model's
one-period prediction from the previous state and inputs, low-pass filtered
(``DISTURBANCE_GAIN``), is added to every predicted period (an additive state
disturbance, constant over the horizon). It needs only the global state sequence, which
a team policy has; with no current and no mismatch it stays at zero up to round-off.

May import: numpy, casadi, ``uvms_env`` and this package (``central_model``,
``policy``, ``reference``, ``rti``, ``settings``, ``ocp``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from nmpc_expert.central_model import CentralFunctions, central_functions
from nmpc_expert.policy import constraint_bounds, local_parameters
from nmpc_expert.reference import GoalIntegral, HorizonReference
from nmpc_expert.rti import FEASIBILITY_TOL, SOFT, solve_daqp
from nmpc_expert.settings import NMPCSettings
from uvms_env.dynamics import NQ, NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.local_model import build_local_model, build_steady_input
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.options import state_structure
from uvms_env.navigation import task_navigator
from uvms_env.policy import AgentSpec
from uvms_env.scenarios import Scenario
from uvms_env.sim.chain import state_size
from uvms_env.sim.simulator import Simulator, grasp_parameters
from uvms_env.team_policy import FULL_INFORMATION, TeamPolicyFactory

# Weight of the squared internal wrench per interval (per N^2 and (N m)^2). The input
# weight R = 0.3 per normalized input squared makes 1 N of thrust (a tenth of a vehicle
# saturation) cost 0.003; at 0.01 a squeeze of 1 N costs three times that, so the plan
# trades thrust for squeeze without letting the squeeze dominate the tracking.
SQUEEZE_WEIGHT = 0.01
# A soft row enters the QP only while its value at the current plan is within this much
# (normalized: a fraction of its limit) of a bound; see ``CentralNMPC._solve_screened``.
SCREEN_MARGIN = 0.3
# Low-pass gain per period of the additive state disturbance (the one-period prediction
# error): 0.3 settles in ~10 periods (1.2 s), far faster than the current changes, while
# averaging the error's period-to-period jitter (contact of the closed chain, integrator).
DISTURBANCE_GAIN = 0.3
# Ridge of the disturbance-cancelling input (``_cancelling_input``), relative to the
# mean squared input sensitivity.
RIDGE = 1e-3
# Relative forward-difference step of the state Jacobian (``central_model``).
FD_STEP = 1e-6
# The expert's per-robot soft constraints (``ocp.CONSTRAINT_NAMES``) without the object
# pitch (index 14), which the team has once per node.
_ROBOT_ROWS = np.r_[0:14, 15, 16]
_OBJECT_PITCH = 14


def central_settings(**changes: Any) -> NMPCSettings:
    """The centralized controller's settings: the paper's controller
    (``NMPCSettings.paper``: the expert's weights, horizon, constraint limits and
    back-offs; no disturbance observer, no input step bound, which answer the local
    model's error), then ``changes``. The tighter angular back-off is kept although the
    team model has no internal-wrench error to cover: the same constraints for both."""
    return NMPCSettings.paper(**changes)  # type: ignore[arg-type]


class CentralNMPC:
    """Centralized NMPC of the whole team (see module docstring); a ``TeamPolicy``."""

    information = FULL_INFORMATION

    def __init__(
        self,
        scenario: Scenario,
        settings: NMPCSettings | None = None,
        squeeze_weight: float = SQUEEZE_WEIGHT,
    ) -> None:
        if not isinstance(scenario, Scenario):
            raise TypeError(f"CentralNMPC needs the Scenario, got {type(scenario).__name__}")
        s = self.settings = settings or central_settings()
        if abs(s.period - scenario.period) > 1e-12:
            raise ValueError(f"settings.period {s.period} != scenario period {scenario.period}")
        if not squeeze_weight >= 0:
            raise ValueError(f"squeeze_weight must be >= 0, got {squeeze_weight}")
        self.scenario = scenario
        self.n = n = scenario.n_agents
        self.horizon = hz = s.horizon
        self.nx, self.nu = state_size(n), NU * n
        self.squeeze_weight = float(squeeze_weight)
        # the model: a simulator of the scenario held at the nominal parameters (its
        # compiled step is the prediction)
        self.model = Simulator(scenario)
        self.model.parameters = np.ascontiguousarray(self.model.nominal_parameters)
        self.model.object_parameters = np.ascontiguousarray(self.model.nominal_object_parameters)
        self.tau_max = np.asarray(self.model.tau_max, dtype=float)
        self.funcs: CentralFunctions = central_functions(
            n,
            scenario.object_shape,
            float(scenario.ring_radius),
            scenario.period,
            scenario.substeps,
            hz + 1,
        )
        self._step = BufferCall(self.funcs.step)
        self._lin = BufferCall(self.funcs.linearization)
        self._grasp = grasp_parameters(scenario)
        # the expert's steady input per robot (``_steady_inputs``): its local model's
        uvms = default_model()
        obj = ObjectModel(scenario.object_shape, scenario.object_ring_radius)
        self._steady_fn = build_steady_input(uvms, obj, build_local_model(uvms, obj))
        self._steady: dict[int, BufferCall] = {}
        self._theta = np.stack(
            [local_parameters(AgentSpec.from_scenario(scenario, i)) for i in range(n)]
        )
        self._steady_inputs(np.zeros((hz, self.nx)), np.zeros((hz, 6)))  # compile it now
        self._vc = np.zeros(3)
        self._h = np.array([scenario.period])
        self._tau = np.zeros((n, NU))
        self._x_in = np.zeros(self.nx)
        self._a0 = np.zeros((n, NU))
        self.disturbance = np.zeros(self.nx)  # additive per period (see module docstring)
        self._previous: tuple[np.ndarray, np.ndarray] | None = None
        o = 2 * NQ * n
        self._velocity_rows = np.r_[NQ * n : 2 * NQ * n, o + 6 : o + 12]
        # Euler angles: each vehicle's q[3:6], the object pose's [3:6]
        self._angles = np.r_[[NQ * i + j for i in range(n) for j in (3, 4, 5)], o + 3, o + 4, o + 5]
        self._eps = np.array([FD_STEP])
        self.navigator = task_navigator(
            scenario.waypoints, scenario.workspace, scenario.obstacles, scenario.team_radius
        )
        self.reference = HorizonReference(self.navigator, hz, s.period, s.attitude_from_waypoint)
        self.goal = GoalIntegral(s, scenario.waypoints)
        self._wp = np.ascontiguousarray(scenario.waypoints, dtype=float)
        self._structure = state_structure(n)
        # soft constraints, normalized: per node, robot-major 16 rows, then the object pitch
        lower, upper, scale = constraint_bounds(s)
        rows_lo = np.r_[np.tile(lower[_ROBOT_ROWS], n), lower[_OBJECT_PITCH]]
        rows_up = np.r_[np.tile(upper[_ROBOT_ROWS], n), upper[_OBJECT_PITCH]]
        self._scale = np.r_[np.tile(scale[_ROBOT_ROWS], n), scale[_OBJECT_PITCH]]
        self._nrow = len(self._scale)  # 16 n + 1 per node
        self._row_lo, self._row_up = rows_lo, rows_up
        self._select, self._manip_rows = self._constraint_selectors()
        nz, nc = hz * self.nu, hz * self._nrow
        self._nz, self._nc = nz, nc
        l1 = np.full(nc, s.slack_l1)
        l2 = np.full(nc, s.slack_l2)
        if np.any(l2 <= 0):
            raise ValueError("slack_l2 must be > 0 (the soft rows need a quadratic penalty)")
        self._soft = (np.r_[np.zeros(nz), 1.0 / (2.0 * l2)], np.r_[np.zeros(nz), l1])
        o = 2 * NQ * n
        self._pose = slice(o, o + 6)
        self._twist = slice(o + 6, o + 12)
        run = np.r_[np.full(6, s.q_x), np.full(6, s.q_v)]
        end = np.r_[np.full(6, s.p_x), np.zeros(6)]  # terminal: pose only (paper's E)
        self._w_res = [run] * (hz - 1) + [end]
        self._r_u = np.full(self.nu, s.r_u)
        self.xbar = np.zeros((hz + 1, self.nx))
        self.abar = np.zeros((hz, n, NU))
        self._a_nodes = np.zeros((hz + 1, n, NU))
        self.has_plan = False
        self.stats: dict[str, Any] = {}
        self.fallbacks = 0
        self.decisions = 0

    # -- TeamPolicy ----------------------------------------------------------------------
    def reset(self) -> None:
        self.has_plan = False
        self.xbar[:] = 0.0
        self.abar[:] = 0.0
        self.disturbance[:] = 0.0
        self._previous = None
        self.goal.reset()
        self.stats = {}
        self.fallbacks = 0
        self.decisions = 0

    def act(self, state: np.ndarray) -> np.ndarray:
        """One team decision from the global state (``state_structure``): (N, 8)."""
        start = time.perf_counter()
        x0, index = self._measure(state)
        self._estimate(x0)
        status, info = "ok", {}
        try:
            self._shift(x0)
            info = self._iterate(x0, index)
            action = self.abar[0].copy()
        except Exception as err:  # a failed solve must never stop the team
            self.fallbacks += 1
            status = f"fallback: {type(err).__name__}: {err}"
            action = self._fallback(x0)
        action = np.clip(action, -1.0, 1.0)
        self._previous = (x0, action)
        self.decisions += 1
        elapsed = (time.perf_counter() - start) * 1e3
        self.stats = {
            "solve_time_ms": elapsed,
            "status": status if status != "ok" else info.get("status", "ok"),
            "fallbacks": self.fallbacks,
            "waypoint_index": index,
            "slow": elapsed > self.settings.fallback_after_ms,
            "disturbance_max": float(np.abs(self.disturbance).max()),
            **{k: v for k, v in info.items() if k != "status"},
        }
        return action

    # -- pieces --------------------------------------------------------------------------
    def _measure(self, state: np.ndarray) -> tuple[np.ndarray, int]:
        st = np.asarray(state)
        size = self._structure["time_fraction"].stop
        if st.shape != (size,):
            raise ValueError(
                f"the team state must have shape ({size},) (env.state() of {self.n} robots), "
                f"got {st.shape}"
            )
        if not np.all(np.isfinite(st)):
            raise ValueError("the team state contains NaN or inf")
        x0 = st[: self.nx].astype(np.float64)
        return x0, self._waypoint_index(st[self._structure["waypoint"]])

    def _waypoint_index(self, waypoint: np.ndarray) -> int:
        d = np.max(np.abs(self._wp - waypoint), axis=1)
        k = int(np.argmin(d))
        if d[k] > 1e-3:
            raise ValueError(
                f"state waypoint {np.round(waypoint, 3).tolist()} is not one of the mission's"
            )
        return k

    def _steady_inputs(self, xs: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """a_ss (K, N, 8) at the team states ``xs`` (K, nx) and object twists ``vd``
        (K, 6): each robot's steady input of the distributed expert (the input that keeps
        it moving rigidly with the object at the twist, carrying its load share of the
        object, at zero acceleration; ``uvms_env.dynamics.local_model``), so that R pulls
        towards the same inputs as in the expert's cost. Their sum balances the object
        (the local models add up to the team's); the squeeze they leave is the cost's."""
        n, k = self.n, len(xs)
        q = xs[:, : NQ * n].reshape(k, n, NQ)
        zeta = xs[:, NQ * n : 2 * NQ * n].reshape(k, n, NQ)
        x_loc = np.ascontiguousarray(np.concatenate([q, zeta], axis=2).reshape(k * n, 2 * NQ))
        twist = np.ascontiguousarray(np.repeat(vd, n, axis=0))
        theta = np.ascontiguousarray(np.tile(self._theta, (k, 1)))
        call = self._steady.get(k)
        if call is None:
            # the horizon's map compiled (the virtual machine took 2.9 ms of a 25 ms
            # decision at N = 6); a single node (the first decision, a fallback) runs on
            # the virtual machine, no compilation for it
            fn = self._steady_fn.map(f"central_steady_n{n}_k{k}", "serial", k * n, [], [])
            call = self._steady[k] = BufferCall(compile_function(fn) if k == self.horizon else fn)
        return call(x_loc, theta, twist)[0].reshape(k, n, NU).copy()

    def _shift(self, x0: np.ndarray) -> None:
        if self.has_plan:
            self.xbar[:-1] = self.xbar[1:].copy()
            self.abar[:-1] = self.abar[1:].copy()
        else:  # no plan: the inputs that hold the team at rest where it is
            self.xbar[:] = x0
            self.abar[:] = self._steady_inputs(x0[None], np.zeros((1, 6)))[0]
        self.xbar[0] = x0

    def _estimate(self, x0: np.ndarray) -> None:
        """Filter the one-period prediction error into the additive disturbance."""
        if self._previous is None:
            return
        error = x0 - self._predict(*self._previous)
        error[self._angles] = wrap_angle(error[self._angles])  # yaw may cross +-pi
        if np.all(np.isfinite(error)):  # a diverged prediction must not poison the plan
            self.disturbance += DISTURBANCE_GAIN * (error - self.disturbance)

    def _predict(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The simulator's period step from ``x`` under normalized inputs ``a`` (N, 8)."""
        self._x_in[:] = x
        np.multiply(a, self.tau_max, out=self._tau)
        p, po = self.model.parameters, self.model.object_parameters
        out = self._step(self._x_in, self._tau, self._vc, p, po, self._grasp, self._h)
        return out[0].reshape(-1).copy()

    def predict(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The prediction model over one period: the state after it (nx,) from the team
        state ``x`` (nx,) under normalized inputs ``a`` (N, 8)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        a = np.asarray(a, dtype=np.float64)
        if x.shape != (self.nx,) or a.shape != (self.n, NU):
            raise ValueError(f"expected x ({self.nx},) and a ({self.n}, {NU})")
        return self._predict(x, a)

    def _cancelling_input(self, gam: np.ndarray) -> np.ndarray:
        """The input change (N*8,) whose one-period effect on the velocities (every
        robot's zeta and the object's twist) best cancels the estimated disturbance's,
        in least squares with a small ridge (directions the inputs barely reach stay
        unused)."""
        if not self.disturbance.any():
            return np.zeros(self.nu)
        rows = self._velocity_rows
        g = gam[rows]
        ridge = RIDGE * np.trace(g.T @ g) / self.nu
        rhs = -g.T @ self.disturbance[rows]
        return np.linalg.solve(g.T @ g + ridge * np.eye(self.nu), rhs)

    def _constraint_selectors(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """State index of every soft row that reads one state entry (-1 for the
        manipulability rows), and each robot's q indices (the manipulability's gradient)."""
        n = self.n
        sel = []
        for i in range(n):
            zeta = NQ * n + NQ * i
            sel += list(range(zeta, zeta + NQ))  # body twist and joint rates
            sel += list(range(NQ * i + 6, NQ * i + NQ))  # joint angles
            sel += [NQ * i + 4, -1]  # vehicle pitch, manipulability
        sel.append(2 * NQ * n + 4)  # object pitch
        return np.array(sel), [np.arange(NQ * i, NQ * (i + 1)) for i in range(n)]

    def _iterate(self, x0: np.ndarray, index: int) -> dict[str, Any]:
        """Build the condensed QP around (xbar, abar), solve it, take the full step."""
        n, hz, nx, nu = self.n, self.horizon, self.nx, self.nu
        x_o = x0[self._pose]
        xd, vd = self.reference(x_o, index)
        xd = xd + self.goal.shift(x_o, index)
        # defects of the exact step along the plan
        defects = np.empty((hz, nx))
        for k in range(hz):
            step = self._predict(self.xbar[k], self.abar[k]) + self.disturbance
            defects[k] = step - self.xbar[k + 1]
        # one compiled call: rhs Jacobians at x0, squeeze along the plan, manipulability
        self._a0[:] = self.abar[0]
        self._a_nodes[:hz] = self.abar
        self._a_nodes[hz] = self.abar[-1]
        p, po = self.model.parameters, self.model.object_parameters
        _, jx_t, ju_t, w_t, wu_t, m_t, jm_t = self._lin(
            np.ascontiguousarray(x0),
            self._a0,
            self.xbar,
            self._a_nodes,
            p,
            po,
            self._grasp,
            self._eps,
        )
        phi, gam = self._discretize(jx_t.T, ju_t.T)
        powers = [gam]  # Phi^j Gamma
        for _ in range(1, hz):
            powers.append(phi @ powers[-1])
        nz = hz * nu
        h_mat = np.diag(np.tile(2.0 * self._r_u, hz))
        a_ref = np.zeros(hz * nu)  # input_reference "zero": the paper's |a|^2_R
        if self.settings.input_reference == "steady_state":
            a_ref = self._steady_inputs(self.xbar[:hz], vd[:hz]).reshape(-1)
            # offset-free: the steady inputs also cancel the estimated disturbance, or R
            # would pull towards inputs that leave it uncompensated (a steady offset)
            a_ref += np.tile(self._cancelling_input(gam), hz)
        f_vec = 2.0 * np.tile(self._r_u, hz) * (self.abar.reshape(-1) - a_ref)
        # the squeeze of every interval: W_k + Wu da_k (state dependence dropped)
        wu = wu_t.T  # (6n, nu)
        if self.squeeze_weight > 0:
            ww = 2.0 * self.squeeze_weight * (wu.T @ wu)
            for k in range(hz):
                blk = slice(k * nu, (k + 1) * nu)
                h_mat[blk, blk] += ww
                f_vec[blk] += 2.0 * self.squeeze_weight * (wu.T @ w_t[k])
        c_rows = np.empty((hz * self._nrow, nz))
        c_const = np.empty(hz * self._nrow)
        ek = np.zeros(nx)
        obj = np.r_[
            np.arange(self._pose.start, self._pose.stop),
            np.arange(self._twist.start, self._twist.stop),
        ]
        sel = self._select
        direct = sel >= 0
        manip = np.flatnonzero(~direct)
        for k in range(1, hz + 1):
            gk = np.zeros((nx, nz))
            for j in range(k):
                gk[:, j * nu : (j + 1) * nu] = powers[k - 1 - j]
            ek = phi @ ek + defects[k - 1]  # e_k = Phi e_{k-1} + defect_{k-1}
            xk = self.xbar[k]
            r = np.r_[
                xk[self._pose][:3] - xd[k, :3],
                wrap_angle(xk[self._pose][3:] - xd[k, 3:]),
                xk[self._twist] - vd[k],
            ]
            w = self._w_res[k - 1]
            jg = gk[obj]
            h_mat += 2.0 * jg.T @ (w[:, None] * jg)
            f_vec += 2.0 * jg.T @ (w * (r + ek[obj]))
            rows = slice((k - 1) * self._nrow, k * self._nrow)
            cr = np.empty((self._nrow, nz))
            cv = np.empty(self._nrow)
            cr[direct] = gk[sel[direct]]
            cv[direct] = xk[sel[direct]] + ek[sel[direct]]
            for i, row in enumerate(manip):
                q_idx = self._manip_rows[i]
                grad = jm_t[k * n + i]
                cr[row] = grad @ gk[q_idx]
                cv[row] = m_t[k, i] + grad @ ek[q_idx]
            c_rows[rows] = cr / self._scale[:, None]
            c_const[rows] = cv / self._scale
        h_mat = 0.5 * (h_mat + h_mat.T)
        lb = -1.0 - self.abar.reshape(-1)
        ub = 1.0 - self.abar.reshape(-1)
        lo_rows = np.tile(self._row_lo, hz) - c_const
        up_rows = np.tile(self._row_up, hz) - c_const
        da, flag, info, kept = self._solve_screened(h_mat, f_vec, c_rows, lb, ub, lo_rows, up_rows)
        cda = c_rows @ da
        slack = max(float(np.max(lo_rows - cda)), float(np.max(cda - up_rows)), 0.0)
        # full step: inputs, and the states through the condensed dynamics
        dab = da.reshape(hz, nu)
        dx = np.zeros(nx)
        for k in range(hz):
            dx = phi @ dx + gam @ dab[k] + defects[k]
            self.xbar[k + 1] += dx
        self.abar += dab.reshape(hz, n, NU)
        np.clip(self.abar, -1.0, 1.0, out=self.abar)
        self.has_plan = True
        squeeze = w_t[0] + wu @ dab[0]
        return {
            "status": {1: "optimal", 2: "soft_optimal"}[flag],
            "iterations": int(info["iterations"]),
            "rows_kept": kept,  # soft rows passed to the QP after screening
            "qp_solves": info["qp_solves"],  # > 1: a screened-out row was violated
            "slack_max": slack,
            "qp_violation": info["qp_violation"],
            "squeeze_rms": float(np.sqrt(np.mean(squeeze**2))),  # planned, first interval
            "defect_max": float(np.abs(defects).max()),
        }

    def _solve_screened(
        self,
        h_mat: np.ndarray,
        f_vec: np.ndarray,
        c_rows: np.ndarray,
        lb: np.ndarray,
        ub: np.ndarray,
        lo_rows: np.ndarray,
        up_rows: np.ndarray,
    ) -> tuple[np.ndarray, int, dict[str, Any], int]:
        """The QP with only the soft rows within ``SCREEN_MARGIN`` of a bound at the
        current plan (da = 0); a left-out row that the solution violates is added and the
        QP solved again. The answer is the full QP's: a solution of the smaller QP that
        satisfies the left-out rows is feasible for the full one at the same cost (their
        slacks are zero), and the full QP's optimum cannot be lower. DAQP's cost grows
        with the rows times the variables squared, and most rows (pitch, joint angles,
        manipulability, speeds away from their limits) are far from their bounds: at
        N = 6, at one state while moving, it kept 153 of the 485 rows."""
        nz = len(f_vec)
        keep = (lo_rows > -SCREEN_MARGIN) | (up_rows < SCREEN_MARGIN)
        for solves in range(1, 5):
            if solves == 4:  # still violating after three: the full QP, every row in
                keep[:] = True
            rows = np.flatnonzero(keep)
            sense = np.r_[np.zeros(nz), np.full(len(rows), SOFT)].astype(np.intc)
            upper, lower = np.r_[ub, up_rows[rows]], np.r_[lb, lo_rows[rows]]
            soft = (
                np.r_[self._soft[0][:nz], self._soft[0][nz + rows]],
                np.r_[self._soft[1][:nz], self._soft[1][nz + rows]],
            )
            c = np.ascontiguousarray(c_rows[rows])
            _, da, flag, info = solve_daqp(None, h_mat, f_vec, c, upper, lower, sense, soft)
            if not np.all(np.isfinite(da)):
                raise RuntimeError("QP solution is not finite")
            viol = max(float(np.max(lb - da)), float(np.max(da - ub)), 0.0)
            if viol > FEASIBILITY_TOL:
                raise RuntimeError(f"QP solution violates the input bounds by {viol:.2e}")
            cda = c_rows @ da
            broken = ~keep & ((cda < lo_rows - FEASIBILITY_TOL) | (cda > up_rows + FEASIBILITY_TOL))
            if not broken.any():
                return da, flag, {**info, "qp_violation": viol, "qp_solves": solves}, len(rows)
            keep |= broken
        raise AssertionError("unreachable: the fourth solve has every row")

    def _discretize(self, jx: np.ndarray, ju: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma) of one period: the simulator's own integrator (``substeps``
        classical RK4 steps) applied to the linearized dynamics x' = Jx x + Ju a. One RK4
        step of a linear system is the 4th-order Taylor polynomial S of expm(dt Jx) (and
        of its integral for the input); ``substeps`` steps are S^substeps, by repeated
        squaring. (scipy's ``expm`` of the same matrix took 3 ms at N = 6: the badly
        scaled Jacobian's norm, ~700 per period, forces many squarings; this is ~0.6 ms.)"""
        steps = self.scenario.substeps
        dt = self.settings.period / steps
        m = dt * jx
        eye = np.eye(len(jx))
        # Horner: S = I + m (I + m/2 (I + m/3 (I + m/4))), U = dt (I + m/2 + m^2/6 + m^3/24) Ju
        p = eye + m / 4
        p = eye + (m @ p) / 3
        taylor = eye + (m @ p) / 2  # I + m/2 + m^2/6 + m^3/24
        s_mat = eye + m @ taylor
        phi, gam = s_mat, dt * (taylor @ ju)
        done = 1
        while done * 2 <= steps:  # doubling: (S^k, Gamma_k) -> (S^2k, S^k Gamma_k + Gamma_k)
            gam = phi @ gam + gam
            phi = phi @ phi
            done *= 2
        for _ in range(steps - done):  # what doubling leaves (steps not a power of 2)
            gam = s_mat @ gam + dt * (taylor @ ju)
            phi = s_mat @ phi
        return phi, gam

    def _fallback(self, x0: np.ndarray) -> np.ndarray:
        """The shifted previous plan's first input, or the steady inputs at rest with no plan
        (zeros if even those cannot be computed)."""
        if self.has_plan:
            return self.abar[0].copy()
        try:
            return self._steady_inputs(x0[None], np.zeros((1, 6)))[0]
        except Exception:  # no input at all rather than a raise in the loop
            return np.zeros((self.n, NU))


def make_central_policy(**settings: Any) -> TeamPolicyFactory:
    """A ``TeamPolicyFactory`` of the centralized NMPC; ``settings``: ``NMPCSettings``
    fields over ``central_settings()``, and ``squeeze_weight``."""
    weight = float(settings.pop("squeeze_weight", SQUEEZE_WEIGHT))
    unknown = sorted(set(settings) - set(NMPCSettings.field_names()))
    if unknown:
        raise ValueError(f"unknown NMPC setting(s) {unknown}; known: {NMPCSettings.field_names()}")
    cfg = central_settings(**settings)

    def build(scenario: Scenario) -> CentralNMPC:
        return CentralNMPC(scenario, cfg, weight)

    return TeamPolicyFactory(build, "nmpc:central")
