"""The fast default solver: a real-time iteration (one Gauss-Newton SQP step per sample).

Per decision: shift the previous plan (warm start), build the condensed QP around it
with one compiled call (``ocp.qp_builder``), solve it with DAQP, check the solution
yourself (finite, status, feasibility of the hard bounds), take the full step and apply
the first input. Why condensed and DAQP: docs/expert.md, "Solvers".

The soft constraints carry the same exact L1 + quadratic slack penalty as the IPOPT
reference (``l1 s + l2 s^2`` per constraint), expressed as DAQP's per-row soft weights
(linear weight l1, reciprocal quadratic weight 1 / (2 l2)); a constraint is violated in
the plan only where satisfying it is impossible or its multiplier exceeds l1.

A failed QP never stalls the loop: the controller applies the shifted previous plan (or,
with no plan yet, the nominal holding input) and counts a fallback.

``RealTimeIteration`` and ``solve_daqp`` (the DAQP call with its own checks and status)
are shared by this robot's ``RTISolver`` and the team's ``central_rti.CentralRTI``, each
saying only how it condenses its QP; the IPOPT reference (``ipopt_solver``) shares the
plan, its shift and the fallback.

May import: numpy, daqp, ``uvms_env`` and this package's ``ocp``/``local_model``.
"""

from __future__ import annotations

from typing import Any, Protocol

import daqp
import numpy as np

from nmpc_expert.ocp import NC, WEIGHT_LAYOUT, OCPFunctions
from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.dynamics.local_model import NX

# Accepted violation of the hard input bounds by the QP solution (normalized inputs).
FEASIBILITY_TOL = 1e-6
SOFT = 8  # DAQP's sense flag of a soft row
# DAQP exit flags that mean "solved" (1: optimal, 2: optimal with soft rows violated)
_SOLVED = {1: "optimal", 2: "soft_optimal"}
_G_T, _E, _A_REF = 7, 8, 9  # ``qp_builder`` outputs g_t and e (see ``ocp.build_qp_builder``)


def violation(values: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """How far ``values`` leave [lower, upper] at most (0 inside)."""
    return max(float(np.max(lower - values)), float(np.max(values - upper)), 0.0)


def solve_daqp(
    qp: daqp.Model | None,
    h: np.ndarray,
    f: np.ndarray,
    c: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    sense: np.ndarray,
    soft: tuple[np.ndarray, np.ndarray],
    hard: np.ndarray | None = None,
) -> tuple[daqp.Model, np.ndarray, np.ndarray, dict[str, Any]]:
    """Load the dense QP min 0.5 x'Hx + f'x s.t. lower <= [x; C x] <= upper (DAQP's
    layout: the first len(x) entries are bounds on x) into ``qp`` (a new model when None),
    solve it and check the solution here, since a solver may stop early and still return
    numbers: finite, and within its hard bounds (the entries not flagged SOFT: the box on
    x and any hard rows) to ``FEASIBILITY_TOL``. ``soft``: (1 / (2 l2), l1) per entry, the
    rows flagged SOFT in ``sense`` carry them; ``hard``: the indices of the entries not
    flagged SOFT, where the caller has them at hand (None: from ``sense``). Returns
    (model, x, C x, info: status, iterations, qp_violation); raises RuntimeError on a
    setup failure, an unsolved QP or a failed check."""
    if qp is None:
        qp = daqp.Model()
        flag, _ = qp.setup(h, f, c, upper, lower, sense)
        if flag < 0:
            raise RuntimeError(f"DAQP setup failed (exit flag {flag})")
        rho, w = soft
        qp.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)
    else:
        # passing ``sense`` resets the active set: a cold start every time (warm starts:
        # docs/expert.md, "Tuning record").
        flag = qp.update(h, f, c, upper, lower, sense)
        if flag < 0:
            raise RuntimeError(f"DAQP update failed (exit flag {flag})")
    x, _, flag, info = qp.solve()
    if flag not in _SOLVED:
        raise RuntimeError(f"DAQP failed (exit flag {flag})")
    if not np.all(np.isfinite(x)):
        raise RuntimeError("QP solution is not finite")
    cx = c @ x
    if hard is None:
        hard = np.flatnonzero(sense != SOFT)
    values = np.concatenate([x, cx])
    viol = violation(values[hard], lower[hard], upper[hard])
    if viol > FEASIBILITY_TOL:
        raise RuntimeError(f"QP solution violates the input bounds by {viol:.2e}")
    status = {"status": _SOLVED[flag], "iterations": int(info["iterations"]), "qp_violation": viol}
    return qp, x, cx, status


def soft_penalties(
    l1: np.ndarray, l2: np.ndarray, n_box: int, n_hard: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """DAQP's per-entry soft weights (1 / (2 l2), l1) of a QP whose ``n_box`` box entries
    come first and ``n_hard`` hard rows last (their entries unused), the soft rows' L1 and
    L2 slack penalties between."""
    l1, l2 = np.asarray(l1, dtype=float), np.asarray(l2, dtype=float)
    if np.any(l2 <= 0):
        raise ValueError("slack_l2 must be > 0 (the soft rows need a quadratic penalty)")
    pad, hard = np.zeros(n_box), np.zeros(n_hard)
    return np.concatenate([pad, 1.0 / (2.0 * l2), hard]), np.concatenate([pad, l1, hard])


class ExtraRows(Protocol):
    """Soft rows added to the QP beyond the builder's (the safety filter's workspace rows):
    ``count`` rows with per-row penalties ``l1``, ``l2``; ``rows(xbar, g, e)`` gives (C,
    lower, upper) in the input steps da, from the condensed dynamics dx = g da + e."""

    count: int
    l1: np.ndarray
    l2: np.ndarray

    def rows(
        self, xbar: np.ndarray, g: np.ndarray, e: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


class RealTimeIteration:
    """A real-time iteration over a horizon of ``n`` intervals: the plan (``xbar``: the
    n + 1 nodes' states, ``abar``: the n inputs, normalized), its warm-start ``shift``, the
    full step along the QP's input steps (``iterate``) and the ``fallback``. A subclass
    builds and solves its condensed QP (``solve_qp``) and says what the input steps do to
    the plan's states (``state_steps``), around the model parameters ``theta``, the OCP's
    ``weights`` and the object references ``xd``, ``vd`` set before each step."""

    def __init__(
        self, horizon: int, nx: int, input_shape: tuple[int, ...], theta: Any, weights: Any
    ) -> None:
        self.n = horizon
        self.theta = np.ascontiguousarray(theta, dtype=float)
        self.weights = np.ascontiguousarray(weights, dtype=float)
        self.xd = np.zeros((horizon + 1, 6))
        self.vd = np.zeros((horizon + 1, 6))
        self.xbar = np.zeros((horizon + 1, nx))  # row k = node k
        self.abar = np.zeros((horizon, *input_shape))
        self.has_plan = False

    def reset(self) -> None:
        self.has_plan = False
        self.xbar[:] = 0.0
        self.abar[:] = 0.0

    def shift(self, x0: np.ndarray, a_init: np.ndarray | None) -> None:
        """Warm start: the previous plan moved one interval forward (last node repeated);
        with no plan, x0 everywhere and ``a_init`` as every input (None only with a plan)."""
        if self.has_plan:
            self.xbar[:-1] = self.xbar[1:].copy()
            self.abar[:-1] = self.abar[1:].copy()
        elif a_init is None:
            raise ValueError("a_init is needed while there is no plan")
        else:
            self.xbar[:] = x0
            self.abar[:] = a_init
        self.xbar[0] = x0

    def step(self, x0: np.ndarray, a_init: np.ndarray | None) -> tuple[np.ndarray, dict[str, Any]]:
        """One real-time iteration from the measured state x0; returns (a_0, info)."""
        self.shift(x0, a_init)
        return self.iterate()

    def iterate(self) -> tuple[np.ndarray, dict[str, Any]]:
        """Solve the QP around the current (xbar, abar) (already shifted), take the full
        step and return (a_0, info); raises RuntimeError if the QP failed."""
        da, info = self.solve_qp()
        self.xbar[1:] += self.state_steps(da)
        self.abar += da.reshape(self.abar.shape)
        np.clip(self.abar, -1.0, 1.0, out=self.abar)
        self.has_plan = True
        return self.abar[0].copy(), info

    def solve_qp(self) -> tuple[np.ndarray, dict[str, Any]]:
        """The input steps da (all inputs of the horizon, flat) and solver info."""
        raise NotImplementedError

    def state_steps(self, da: np.ndarray) -> np.ndarray:
        """dx_1..dx_n (n x nx): the plan's state steps under the input steps ``da`` of the
        last ``solve_qp`` (its linearization and defects)."""
        raise NotImplementedError

    def fallback(self, x0: np.ndarray, a_hold: np.ndarray) -> np.ndarray:
        """The shifted previous plan's first input (already shifted by ``step``), or the
        holding input when there is no plan."""
        if self.has_plan:
            return self.abar[0].copy()
        return np.clip(a_hold, -1.0, 1.0)


class RTISolver(RealTimeIteration):
    """Real-time iteration for one robot: ``step(x0, a_init)`` -> (first input (8,), info),
    around the references ``xd``, ``vd`` set beforehand."""

    name = "rti"

    def __init__(
        self,
        funcs: OCPFunctions,
        theta: np.ndarray,
        weights: np.ndarray,
        cost: tuple[np.ndarray, np.ndarray] | None = None,
        extra: ExtraRows | None = None,
        max_step: float | None = None,
    ) -> None:
        """``cost``: a fixed (H, f) of the QP in place of the builder's Gauss-Newton
        tracking cost (the safety filter's input-only cost); the dynamics, constraints
        and bounds are the builder's either way. ``extra``: soft rows appended to the
        builder's (the safety filter's workspace rows). ``max_step``: hard bounds
        |a_k - a_{k-1}| <= max_step along the plan (k >= 1, hard rows after the soft
        ones), and, while ``a_prev`` (the input applied last period) is set, on the first
        input |a_0 - a_prev| <= max_step (its box, intersected with [-1, 1]); None: none."""
        n = funcs.horizon
        # xbar's row k = node k: CasADi's column-major NX x N+1, as the builder reads it
        super().__init__(n, NX, (NU,), theta, weights)
        self.funcs = funcs
        self._build = BufferCall(funcs.qp_builder)
        # d: added to every interval's predicted end state (the disturbance observer's
        # estimate, written in place by the controller; zeros: the paper's model)
        self.disturbance = np.zeros(NX)
        # a shift of the steady-state input reference a_ss of every interval (written in
        # place by the controller: the input that cancels d; zeros: the paper's cost)
        self.input_offset = np.zeros(NU)
        self.stats: dict[str, Any] = {}
        nz, nc = n * NU, n * NC
        self._nz = nz
        self.extra = extra
        if extra is not None:
            nc += extra.count
        self._nsoft = nc
        self.max_step = None if max_step is None else float(max_step)
        self.a_prev: np.ndarray | None = None  # the input applied last period (max_step)
        n_step = 0
        if self.max_step is not None:
            if not self.max_step > 0:
                raise ValueError("max_step must be > 0")
            n_step = NU * (n - 1)  # a_k - a_{k-1} = da_k - da_{k-1} + (abar_k - abar_{k-1})
            self._step_c = np.eye(n_step, nz, NU) - np.eye(n_step, nz)
        # [box on da; soft rows; hard step rows], DAQP's layout
        self._upper = np.zeros(nz + nc + n_step)
        self._lower = np.zeros(nz + nc + n_step)
        self._sense = np.concatenate([np.zeros(nz), np.full(nc, SOFT), np.zeros(n_step)]).astype(
            np.intc
        )
        self._hard = np.flatnonzero(self._sense != SOFT)
        # C: the builder's soft rows, the extra rows, the step rows (constant)
        self._c = np.zeros((nc + n_step, nz))
        if n_step:
            self._c[nc:] = self._step_c
        # the builder writes its bounds and rows where DAQP reads them (no copies)
        nb = n * NC
        views = {
            2: self._c[:nb],  # c_t: C row by row
            3: self._lower[:nz],  # lb
            4: self._upper[:nz],  # ub
            5: self._lower[nz : nz + nb],  # lbc
            6: self._upper[nz : nz + nb],  # ubc
        }
        for i, view in views.items():
            self._build.bind_output(i, view)
        self._r_twice = 2.0 * np.tile(self.weights[WEIGHT_LAYOUT["r_u"]], n)
        l1 = np.tile(self.weights[WEIGHT_LAYOUT["slack_l1"]], n)
        l2 = np.tile(self.weights[WEIGHT_LAYOUT["slack_l2"]], n)
        if extra is not None:
            l1 = np.concatenate([l1, extra.l1])
            l2 = np.concatenate([l2, extra.l2])
        self._soft = soft_penalties(l1, l2, nz, n_step)
        self._qp: daqp.Model | None = None
        self.cost = cost
        self._loaded = False  # the builder's outputs were set by ``load_build``

    def build_inputs(self) -> tuple[np.ndarray, ...]:
        """The QP builder's inputs around the current (xbar, abar), in its order: what
        ``solve_qp`` would evaluate it on (for a caller that evaluates many at once)."""
        return (self.xbar, self.abar, self.theta, self.xd, self.vd, self.weights, self.disturbance)

    def load_build(self, outputs: list[np.ndarray]) -> None:
        """The builder's outputs on ``build_inputs()``, evaluated elsewhere (column-major
        nonzeros, as CasADi lays them out): the next ``solve_qp`` uses them instead of
        evaluating the builder itself."""
        for mine, theirs in zip(self._build.outputs, outputs, strict=True):
            mine.reshape(-1)[:] = theirs
        self._loaded = True

    def reset(self) -> None:
        super().reset()
        self._loaded = False
        self.a_prev = None
        self._qp = None

    def solve_qp(self) -> tuple[np.ndarray, dict[str, Any]]:
        """Build and solve the condensed QP around (xbar, abar); returns the input steps
        da (N * 8) and solver info; raises RuntimeError if the QP failed. The builder
        writes the bounds and the soft rows into DAQP's arrays (``__init__``)."""
        if self._loaded:
            built, self._loaded = self._build.outputs, False
        else:
            built = self._build(*self.build_inputs())
        h, f = built[0], built[1].reshape(-1)
        nz, ns, nb = self._nz, self._nz + self._nsoft, self.n * NC
        lbc, ubc = self._lower[nz:ns], self._upper[nz:ns]
        if self.cost is not None:
            h, f = self.cost
        elif self.input_offset.any():
            # a_ref -> clip(a_ref + offset): f = 2 R (abar - a_ref) moves by -2 R (shift)
            a_ref = built[_A_REF]  # (N, 8): interval k's reference in row k
            shift = np.clip(a_ref + self.input_offset, -1.0, 1.0) - a_ref
            f = f - self._r_twice * shift.reshape(-1)
        if self.extra is not None:
            out = self._build.outputs
            c_x, lo_x, up_x = self.extra.rows(self.xbar, out[_G_T], out[_E].reshape(-1))
            self._c[nb : self._nsoft] = c_x
            self._lower[nz + nb : ns], self._upper[nz + nb : ns] = lo_x, up_x
        if self.max_step is not None:
            d = self.max_step
            if self.a_prev is not None:  # |a_0 - a_prev| <= d, within the [-1, 1] box
                lo0 = np.maximum(self._lower[:NU], self.a_prev - d - self.abar[0])
                self._upper[:NU] = np.maximum(
                    lo0, np.minimum(self._upper[:NU], self.a_prev + d - self.abar[0])
                )
                self._lower[:NU] = lo0
            diff = (self.abar[1:] - self.abar[:-1]).reshape(-1)
            self._lower[ns:], self._upper[ns:] = -d - diff, d - diff
        self._qp, da, cda, info = solve_daqp(
            self._qp, h, f, self._c, self._upper, self._lower, self._sense, self._soft, self._hard
        )
        return da, {
            "status": info["status"],
            # largest planned soft-constraint violation (normalized)
            "slack_max": violation(cda[: ns - nz], lbc, ubc),
            "iterations": info["iterations"],  # active-set iterations
            "qp_violation": info["qp_violation"],
        }

    def state_steps(self, da: np.ndarray) -> np.ndarray:
        out = self._build.outputs
        g_t, e = out[_G_T], out[_E]  # dx_1..dx_N = G da + e (G read row-major from G')
        return (g_t @ da + e.reshape(-1)).reshape(self.n, NX)

    def input_sensitivity(self) -> np.ndarray | None:
        """Gamma_0 = d x_1 / d a_0 (NX x NU) of the last linearization, None before any."""
        if not self.has_plan:
            return None
        return self._build.outputs[_G_T][:NX, :NU]
