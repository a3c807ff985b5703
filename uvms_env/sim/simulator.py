"""The truth simulator: integrate the closed chain one control period per call.

    sim = Simulator(make("paper"))
    sim.reset(seed=0)
    info = sim.step(tau)          # tau: (N, 8) physical units, saturated inside
    sim.state.q, sim.state.zeta, sim.state.x_O, sim.state.v_O, sim.state.t

The whole control period (RK4 substeps, KKT solves) is one compiled CasADi call made
through the zero-copy buffer interface; the compiled library is cached on disk.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from uvms_env.dynamics import NP, NQ, NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall, RebuiltOnUnpickle, compile_function
from uvms_env.dynamics.payload import NPO, OBJECT_PARAMETER_LAYOUT
from uvms_env.dynamics.spatial import SINGULARITY_MARGIN, rot_zyx
from uvms_env.dynamics.uvms import PARAMETER_LAYOUT, default_model, scale_damping
from uvms_env.sim.chain import ChainFunctions, build_chain, state_size
from uvms_env.sim.current import OceanCurrent

if TYPE_CHECKING:  # the simulator reads a scenario's fields; it does not import the layer
    from uvms_env.scenarios import Scenario

# Grasp stabilization rate w [1/s] (Baumgarte; why 10: docs/model.md, "The closed chain").
STABILIZATION = 10.0
# Error control (docs/model.md). Every period ends with a projection onto the grasp
# manifold inside the compiled step; how far the integrated state had drifted from it
# before (pose and twist residuals) is the accuracy check. A period whose drift exceeds
# these bounds is integrated again as two halves, recursively.
DRIFT_TOL_POSE = 1e-5  # m and rad
DRIFT_TOL_TWIST = 1e-4  # m/s and rad/s
MAX_REFINEMENTS = 4  # halvings: down to 1/16 of a period (128 substeps at the default 8)
# What the simulator promises at the end of every period (README): the grasp pose error
# after the projection. One Newton step from an accepted drift lands at ~1e-9 or below.
GRASP_TOL = 1e-6  # m and rad
# The physical envelope: no input the saturations admit drives a UVMS or the object near
# these speeds with the model's damping (docs/model.md, "Divergence"). A state beyond them
# means the model was driven out of its validity (e.g. damping_scale=0): refused as diverged.
SPEED_LIMITS = {"linear": 5.0, "angular": 10.0, "joint": 20.0}  # m/s, rad/s, rad/s
# Fraction of ``mismatch`` applied to weighed quantities (masses, displaced volumes).
WEIGHED_FRACTION = 0.1


@cache
def _chain(
    n: int, shape: str, ring_radius: float, period: float, substeps: int
) -> tuple[ChainFunctions, object]:
    uvms = default_model()
    obj = ObjectModel(shape, ring_radius)
    chain = build_chain(n, uvms, obj, period, substeps, STABILIZATION)
    return chain, compile_function(chain.step)


def compiled_chain(
    n: int, shape: str, ring_radius: float, period: float, substeps: int
) -> tuple[ChainFunctions, cs.Function]:
    """The closed chain of ``n`` robots and its compiled period step, the very ones the
    simulator integrates with (one build per process, the library cached on disk): for a
    controller whose prediction model is the simulator's (``nmpc_expert.central``)."""
    return _chain(n, shape, float(ring_radius), period, substeps)  # type: ignore[return-value]


def grasp_parameters(scenario: Scenario) -> np.ndarray:
    """The grasps (N, NG) as the chain's functions read them: offset l_i, then R_Oi
    column-major (C order of this array = CasADi's NG x N)."""
    s = scenario
    rot = s.grasp_rotations.transpose(0, 2, 1).reshape(s.n_agents, 9)
    return np.ascontiguousarray(np.hstack([s.grasp_offsets, rot]))


@cache
def _internal_wrench_function(n: int, shape: str, ring_radius: float, period: float, substeps: int):
    chain, _ = _chain(n, shape, ring_radius, period, substeps)
    return compile_function(chain.internal_wrench)


@dataclass
class SimState:
    """Views into the simulator's flat state vector (read-only by convention)."""

    q: np.ndarray  # (N, 10)
    zeta: np.ndarray  # (N, 10)
    x_O: np.ndarray  # (6,)
    v_O: np.ndarray  # (6,)
    t: float


@dataclass
class StepInfo:
    tau_applied: np.ndarray  # (N, 8) after saturation
    saturated: np.ndarray  # (N, 8) bool: the request exceeded the limit
    current: np.ndarray  # (3,) inertial current velocity during the period


def draw_truth_parameters(
    s: Scenario,
    nominal: np.ndarray,
    nominal_object: np.ndarray,
    rng: np.random.Generator,
    mismatch: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """An episode's truth model: the robots' (N, NP) and the object's (NPO,) parameters,
    perturbed by ``mismatch`` (None: the scenario's) and scaled by its ``damping_scale``."""
    p = nominal.copy()
    po = nominal_object.copy()
    m = s.mismatch if mismatch is None else float(mismatch)
    if m > 0:
        # Hydrodynamic coefficients (added mass, damping, drag scales, joint friction)
        # are uncertain by +-mismatch. Masses and displaced volumes are weighed and
        # trimmed before a dive, so they get a tenth of it: a 10% volume error would
        # be 13 N of buoyancy on a 10 N heave saturation, a task no controller can do.
        rel = np.full(p.shape[1], 1.0)
        rel[PARAMETER_LAYOUT["vehicle_displaced_volume"]] = WEIGHED_FRACTION
        p = p * (1 + m * rel * rng.uniform(-1, 1, p.shape))
        # the extra-mass entry is an absolute kg value around 0: perturb the vehicle mass
        p[:, PARAMETER_LAYOUT["vehicle_extra_mass"]] = (
            m
            * WEIGHED_FRACTION
            * rng.uniform(-1, 1, (len(p), 1))
            * default_model().params.vehicle.mass
        )
        rel_o = np.full(po.shape, 1.0)
        rel_o[OBJECT_PARAMETER_LAYOUT["mass"]] = WEIGHED_FRACTION
        rel_o[OBJECT_PARAMETER_LAYOUT["displaced_volume"]] = WEIGHED_FRACTION
        po = po * (1 + m * rel_o * rng.uniform(-1, 1, po.shape))
    p = np.ascontiguousarray(np.stack([scale_damping(pi, s.damping_scale) for pi in p]))
    po[3] *= s.damping_scale  # object drag scale
    return p, np.ascontiguousarray(po)


class SimulationDiverged(FloatingPointError):
    """A period could not be integrated to the promised accuracy, or left the model's
    physical envelope; the simulator kept the last valid state."""


class Simulator(RebuiltOnUnpickle):
    """Truth simulation of a scenario (see module docstring). Picklable and deep-copyable:
    a copy continues the same episode bit for bit."""

    _rebuilt = (
        "uvms",
        "object",
        "chain",
        "_step",
        "_x_next",
        "_drift",
        "_error",
        "_drift_abs",
        "_internal",
    )

    def __init__(self, scenario: Scenario) -> None:
        self._init_args = (scenario,)
        self.scenario = scenario
        s = scenario
        self.n = s.n_agents
        self.uvms = default_model()
        self.object = ObjectModel(s.object_shape, s.ring_radius)
        self.chain, step_fn = _chain(
            self.n, s.object_shape, float(s.ring_radius), s.period, s.substeps
        )
        self._step = BufferCall(step_fn)
        self.tau_max = self.uvms.params.limits.tau_max
        self._x = np.zeros(state_size(self.n))
        self._x_next = self._step.outputs[0].reshape(-1)  # a view
        self._drift, self._error = self._step.outputs[1:]  # (N, 12), (N, 6)
        self._x_part = np.zeros_like(self._x)  # start of a refined part of a period
        self._h = np.array([s.period])
        self.refinements = 0  # periods integrated in parts (diagnostics)
        self._drift_abs = np.zeros_like(self._drift)
        lin, ang, joint = (SPEED_LIMITS[k] for k in ("linear", "angular", "joint"))
        self._zeta_limits = np.tile(np.r_[[lin] * 3, [ang] * 3, [joint] * 4], self.n)
        self._object_speed_limits = np.r_[[lin] * 3, [ang] * 3]
        self._drift_tol = np.tile(np.r_[[DRIFT_TOL_POSE] * 6, [DRIFT_TOL_TWIST] * 6], (self.n, 1))
        self._internal: BufferCall | None = None
        self._tau_wrench = np.zeros((self.n, NU))
        self._tau = np.zeros((self.n, NU))
        self._vc = np.zeros(3)
        self._grasp = grasp_parameters(s)
        self.nominal_parameters = np.tile(self.uvms.nominal_parameters(), (self.n, 1))
        self.nominal_object_parameters = self.object.nominal_parameters()
        self.parameters = np.zeros((self.n, NP))
        self.object_parameters = np.zeros(NPO)
        self.current_model = OceanCurrent(self.uvms.params.currents[s.current])
        self.t = 0.0
        self.reset(seed=s.seed)

    # -- state -------------------------------------------------------------------------
    @property
    def state(self) -> SimState:
        n = self.n
        x = self._x
        return SimState(
            q=x[: NQ * n].reshape(n, NQ),
            zeta=x[NQ * n : 2 * NQ * n].reshape(n, NQ),
            x_O=x[2 * NQ * n : 2 * NQ * n + 6],
            v_O=x[2 * NQ * n + 6 :],
            t=self.t,
        )

    @property
    def flat_state(self) -> np.ndarray:
        return self._x

    def set_state(self, q: np.ndarray, zeta: np.ndarray, x_o: np.ndarray, v_o: np.ndarray) -> None:
        """Overwrite the state (no consistency projection: use for tests and replays)."""
        n = self.n
        self._x[: NQ * n] = np.asarray(q, float).reshape(-1)
        self._x[NQ * n : 2 * NQ * n] = np.asarray(zeta, float).reshape(-1)
        self._x[2 * NQ * n : 2 * NQ * n + 6] = x_o
        self._x[2 * NQ * n + 6 :] = v_o

    # -- episode -----------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, current: str | None = None, mismatch: float | None = None
    ) -> SimState:
        """Back to the scenario's start at rest; draws the truth model and the current,
        under the scenario's current preset and mismatch or this episode's ``current``
        and ``mismatch`` (``uvms_env.env.conditions``)."""
        s = self.scenario
        rng = np.random.default_rng(seed if seed is not None else s.seed)
        self.parameters, self.object_parameters = draw_truth_parameters(
            s, self.nominal_parameters, self.nominal_object_parameters, rng, mismatch
        )
        preset = self.uvms.params.currents[current or s.current]
        if preset is not self.current_model.preset:
            self.current_model = OceanCurrent(preset)
        self.current_model.reset(rng)
        self.set_state(s.initial_q, np.zeros((self.n, NQ)), s.object_start, np.zeros(6))
        self.t = 0.0
        return self.state

    def step(self, tau: np.ndarray) -> StepInfo:
        """Advance one control period with inputs ``tau`` (N, 8), saturated at the limits."""
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.n, NU):
            raise ValueError(f"tau must have shape ({self.n}, {NU}), got {tau.shape}")
        if not np.isfinite(tau.sum()):  # one reduction: NaN and inf survive a sum
            bad = np.argwhere(~np.isfinite(tau))[0]
            raise ValueError(f"tau contains NaN or inf (robot {bad[0]}, input {bad[1]})")
        saturated = np.abs(tau) > self.tau_max
        np.clip(tau, -self.tau_max, self.tau_max, out=self._tau)
        self._vc[:] = self.current_model.step(self.scenario.period)
        if not self._evaluate(self._x, self.scenario.period):
            self.refinements += 1
            self._x_part[:] = self._x
            reason = self._refine(self._x_part, self.scenario.period, 1)
            if reason:
                raise SimulationDiverged(f"the simulation diverged at t = {self.t:.2f} s: {reason}")
        self._check_envelope()
        self._x[:] = self._x_next
        self.t += self.scenario.period
        return StepInfo(self._tau.copy(), saturated, self._vc.copy())

    def _evaluate(self, x: np.ndarray, h: float) -> bool:
        """One compiled call: the period part of length ``h`` from ``x`` (results in
        ``_x_next``, ``_drift``, ``_error``); whether it passed the error control."""
        self._h[0] = h
        self._step(
            x, self._tau, self._vc, self.parameters, self.object_parameters, self._grasp, self._h
        )
        return self._accurate()

    def _accurate(self) -> bool:
        """The last compiled call's error control (see DRIFT_TOL_POSE). Few numpy calls:
        this runs every period. NaN compares False, so a non-finite drift or error is
        inaccurate; a non-finite state has a non-finite error."""
        np.abs(self._drift, out=self._drift_abs)
        ok = bool((self._drift_abs <= self._drift_tol).all())
        return ok and bool(np.abs(self._error).max() <= GRASP_TOL)

    @property
    def last_drift(self) -> float:
        """Largest pose drift (m, rad) before the projection in the last compiled call."""
        return float(np.abs(self._drift[:, :6]).max())

    def _refine(self, x: np.ndarray, h: float, level: int) -> str:
        """Integrate ``x`` over ``h`` as two halves (each refined again if needed); the
        result lands in ``self._x_next`` and ``x`` is overwritten. '' or why it failed."""
        if level > MAX_REFINEMENTS:
            return self._failure_reason(x)
        for _ in range(2):
            if not self._evaluate(x, h / 2):
                reason = self._refine(x, h / 2, level + 1)
                if reason:
                    return reason
            x[:] = self._x_next
        return ""

    def _failure_reason(self, x: np.ndarray) -> str:
        n = self.n
        pitches = np.r_[x[2 * NQ * n + 4], x[4 : NQ * n : NQ]]  # object, then vehicles
        worst = int(np.argmax(np.abs(pitches)))
        text = (
            f"a 1/{2**MAX_REFINEMENTS} part of the period still drifted "
            f"{self.last_drift:.2e} from the grasps"
        )
        if abs(pitches[worst]) > np.pi / 2 - SINGULARITY_MARGIN:
            body = "the object" if worst == 0 else f"vehicle {worst - 1}"
            text += (
                f"; {body} is pitched {pitches[worst]:.3f} rad, at the singularity of the "
                "state's ZYX Euler angles (|theta| = pi/2)"
            )
        return text

    def _check_envelope(self) -> None:
        n, x = self.n, self._x_next
        # every period: two comparisons against per-entry limits; the message only on failure
        if (np.abs(x[NQ * n : 2 * NQ * n]) <= self._zeta_limits).all() and (
            np.abs(x[2 * NQ * n + 6 :]) <= self._object_speed_limits
        ).all():
            return
        zeta = x[NQ * n : 2 * NQ * n].reshape(n, NQ)
        v_o = x[2 * NQ * n + 6 :]
        speeds = {
            "linear": max(np.abs(zeta[:, :3]).max(), np.abs(v_o[:3]).max()),
            "angular": max(np.abs(zeta[:, 3:6]).max(), np.abs(v_o[3:]).max()),
            "joint": np.abs(zeta[:, 6:]).max(),
        }
        for kind, value in speeds.items():
            if not value <= SPEED_LIMITS[kind]:
                raise SimulationDiverged(
                    f"the simulation diverged at t = {self.t:.2f} s: the {kind} speed "
                    f"{value:.3g} is beyond the model's envelope ({SPEED_LIMITS[kind]})"
                )

    # -- diagnostics -------------------------------------------------------------------
    def grasp_error(self) -> tuple[np.ndarray, np.ndarray]:
        """Per grasp: position error (m) and orientation error (rad) of the end effector."""
        pos, rot, _ = self.chain.grasp_error(self._x, self._grasp.T)
        return np.linalg.norm(np.array(pos), axis=0), np.linalg.norm(np.array(rot), axis=0)

    def wrenches(self, tau: np.ndarray | None = None) -> np.ndarray:
        """lambda_i (N, 6): wrench each UVMS applies to the object at its grasp point
        (inertial frame, [force; moment]) under inputs ``tau`` (default: the last applied)."""
        tau = self._tau if tau is None else np.clip(tau, -self.tau_max, self.tau_max)
        lam = self.chain.wrenches(
            self._x, tau.T, self._vc, self.parameters.T, self.object_parameters, self._grasp.T
        )
        return np.array(lam).T

    def internal_wrench(self, tau: np.ndarray | None = None) -> np.ndarray:
        """The squeeze (N, 6): the part of the grasp wrenches that cancels on the object
        (null space of the grasp matrix G^T = [J_O1^T ... J_ON^T]), under inputs ``tau``
        (default: the last applied) and the current of the last period. Compiled."""
        if self._internal is None:
            fn = _internal_wrench_function(
                self.n,
                self.scenario.object_shape,
                float(self.scenario.ring_radius),
                self.scenario.period,
                self.scenario.substeps,
            )
            self._internal = BufferCall(fn)
        if tau is not None:  # into a fixed buffer: re-binding a new array costs
            np.clip(tau, -self.tau_max, self.tau_max, out=self._tau_wrench)
        else:
            self._tau_wrench[:] = self._tau
        out = self._internal(
            self._x,
            self._tau_wrench,
            self._vc,
            self.parameters,
            self.object_parameters,
            self._grasp,
        )[0]
        return out.copy()

    def grasp_matrix_t(self) -> np.ndarray:
        """G^T (6 x 6N), maps stacked grasp wrenches to the object wrench at its centroid."""
        r_o = np.array(rot_zyx(self.state.x_O[3:]))
        blocks = []
        for l_i in self.scenario.grasp_offsets:
            a = r_o @ l_i
            s = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            blocks.append(np.block([[np.eye(3), np.zeros((3, 3))], [s, np.eye(3)]]))
        return np.hstack(blocks)

    def energy(self) -> float:
        """Kinetic (rigid + added mass) plus weight/buoyancy potential of all bodies, J."""
        st = self.state
        e = float(self.object.energy(st.x_O, st.v_O, self.object_parameters))
        for q, z, p in zip(st.q, st.zeta, self.parameters, strict=True):
            m = np.array(self.uvms.mass_matrix(q, p))
            e += 0.5 * z @ m @ z + float(self.uvms.potential(q, p))
        return e

    def holding_inputs(self) -> np.ndarray:
        """Inputs (N, 8) of least normalized effort that hold the current configuration at
        rest (zero acceleration), from the static balance of every body:
        B tau_i - J_i^T lambda_i = g_i(q_i) and sum_i J_Oi^T lambda_i = g_O."""
        st, n = self.state, self.n
        b = self.uvms.B
        rows = 10 * n + 6
        a = np.zeros((rows, NU * n + 6 * n))
        rhs = np.zeros(rows)
        g_t = self.grasp_matrix_t()
        for i in range(n):
            _, h = self.uvms.dynamics(st.q[i], np.zeros(NQ), np.zeros(3), self.parameters[i])
            jac = np.array(self.uvms.ee_jacobian(st.q[i]))
            a[10 * i : 10 * i + 10, NU * i : NU * i + NU] = b * self.tau_max  # x = tau / tau_max
            a[10 * i : 10 * i + 10, NU * n + 6 * i : NU * n + 6 * i + 6] = -jac.T
            rhs[10 * i : 10 * i + 10] = np.array(h).ravel()
        _, h_o = self.object.dynamics(st.x_O, np.zeros(6), np.zeros(3), self.object_parameters)
        a[10 * n :, NU * n :] = g_t
        rhs[10 * n :] = np.array(h_o).ravel()
        # least normalized effort; the wrenches carry a tiny weight only to pick one of the
        # equivalent internal squeezes: KKT of min x'Wx s.t. A x = rhs
        nx = a.shape[1]
        w = np.concatenate([np.ones(NU * n), 1e-6 * np.ones(6 * n)])
        kkt = np.block([[np.diag(w), a.T], [a, np.zeros((rows, rows))]])
        sol = np.linalg.lstsq(kkt, np.concatenate([np.zeros(nx), rhs]), rcond=None)[0][:nx]
        residual = np.linalg.norm(a @ sol - rhs)
        if residual > 1e-8:
            raise ValueError(
                f"no static balance exists for this configuration (residual {residual:.2e})"
            )
        return (sol[: NU * n] * np.tile(self.tau_max, n)).reshape(n, NU)
