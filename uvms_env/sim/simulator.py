"""The truth simulator: integrate the closed chain one control period per call.

    sim = Simulator(make("paper"))
    sim.reset(seed=0)
    info = sim.step(tau)          # tau: (N, 8) physical units, saturated inside
    sim.state.q, sim.state.zeta, sim.state.x_O, sim.state.v_O, sim.state.t

The whole control period (RK4 substeps, KKT solves) is one compiled CasADi call made
through the zero-copy buffer interface; the compiled library is cached on disk, and
compiled (or loaded) at the first period, so a simulator built to read a scenario (its
start, grasps, holding inputs) compiles nothing. Its error
control, envelope and current are the batched simulator's, on one environment:
``uvms_env.sim.period`` and ``uvms_env.sim.current``.
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
from uvms_env.sim.current import Currents
from uvms_env.sim.period import (
    ENVELOPE,
    MAX_REFINEMENTS,
    OK,
    SPEED_LIMITS,
    PeriodControl,
    envelope_excess,
)

if TYPE_CHECKING:  # the simulator reads a scenario's fields; it does not import the layer
    from uvms_env.scenarios import Scenario

# Grasp stabilization rate w [1/s] (Baumgarte; why 10: docs/model.md, "The closed chain").
STABILIZATION = 10.0
# Fraction of ``mismatch`` applied to weighed quantities (masses, displaced volumes).
WEIGHED_FRACTION = 0.1


@cache
def _capacity(shape: str, size: float) -> int:
    return ObjectModel(shape, size).capacity


@cache
def chain_functions(n: int, capacity: int, period: float, substeps: int) -> ChainFunctions:
    """The closed chain of ``n`` robots for every object of a strip ``capacity``
    (``ObjectModel.capacity``), symbolic (built once per process)."""
    obj = ObjectModel.of_capacity(capacity)
    return build_chain(n, default_model(), obj, period, substeps, STABILIZATION)


@cache
def chain_of_capacity(
    n: int, capacity: int, period: float, substeps: int
) -> tuple[ChainFunctions, cs.Function]:
    """``compiled_chain`` for every object of a strip ``capacity``
    (``ObjectModel.capacity``)."""
    chain = chain_functions(n, capacity, period, substeps)
    return chain, compile_function(chain.step)


def symbolic_chain(n: int, shape: str, size: float, period: float, substeps: int) -> ChainFunctions:
    """The closed chain the simulator integrates with, symbolic (nothing compiled): for
    builds of its own, e.g. the batched simulator's lanes. ``size``: the object's."""
    return chain_functions(n, _capacity(shape, float(size)), period, substeps)


def compiled_chain(
    n: int, shape: str, size: float, period: float, substeps: int
) -> tuple[ChainFunctions, cs.Function]:
    """The closed chain of ``n`` robots and its compiled period step, the very ones the
    simulator integrates with (one build per process and strip capacity, the library
    cached on disk): for a controller whose prediction model is the simulator's
    (``nmpc_expert.central``). ``size``: the object's (``Scenario.object_size``); every
    object of its strip capacity shares them (the object is in P_O)."""
    return chain_of_capacity(n, _capacity(shape, float(size)), period, substeps)


def grasp_parameters(scenario: Scenario) -> np.ndarray:
    """The grasps (N, NG) as the chain's functions read them: offset l_i, then R_Oi
    column-major (C order of this array = CasADi's NG x N)."""
    s = scenario
    rot = s.grasp_rotations.transpose(0, 2, 1).reshape(s.n_agents, 9)
    return np.ascontiguousarray(np.hstack([s.grasp_offsets, rot]))


@cache
def _internal_wrench_function(n: int, capacity: int, period: float, substeps: int):
    chain, _ = chain_of_capacity(n, capacity, period, substeps)
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
    """An episode's truth model: the robots' (N, NP) and the object's parameters (its p_O),
    perturbed by ``mismatch`` (None: the scenario's) and scaled by its ``damping_scale``.
    Only the object's physical parameters (its first ``NPO``) are uncertain, not its
    shape."""
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
        rel_o = np.full(NPO, 1.0)
        rel_o[OBJECT_PARAMETER_LAYOUT["mass"]] = WEIGHED_FRACTION
        rel_o[OBJECT_PARAMETER_LAYOUT["displaced_volume"]] = WEIGHED_FRACTION
        po[:NPO] = po[:NPO] * (1 + m * rel_o * rng.uniform(-1, 1, NPO))
    p = np.ascontiguousarray(np.stack([scale_damping(pi, s.damping_scale) for pi in p]))
    po[OBJECT_PARAMETER_LAYOUT["drag_scale"]] *= s.damping_scale
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
        "_drift",
        "_outputs",
        "_x_column",
        "control",
        "_internal",
    )

    def __init__(self, scenario: Scenario) -> None:
        self._init_args = (scenario,)
        self.scenario = scenario
        s = scenario
        self.n = s.n_agents
        self.uvms = default_model()
        self.object = ObjectModel(s.object_shape, s.object_size)
        self.chain_key = (s.object_shape, float(s.object_size), s.period, s.substeps)
        capacity = _capacity(s.object_shape, float(s.object_size))
        self._chain_args = (self.n, capacity, s.period, s.substeps)
        self.chain = chain_functions(*self._chain_args)
        # compiled at the first period: a simulator built to read a scenario (its start,
        # grasps, holding inputs) compiles nothing
        self._step: BufferCall | None = None
        self.tau_max = self.uvms.params.limits.tau_max
        self._tau_min = -self.tau_max
        self._x = np.zeros(state_size(self.n))
        self._x_column = self._x[:, None]  # the period routine's layout, (element, K = 1)
        self._outputs: tuple[np.ndarray, ...] = ()
        self._drift = np.zeros((self.n, 12))
        self._x_part = np.zeros_like(self._x)  # start of a refined part of a period
        self._ids = np.zeros(1, np.int64)  # the one environment, as the refinement indexes
        self._h = np.array([s.period])
        self.refinements = 0  # periods integrated in parts (diagnostics)
        self.control = PeriodControl(self.n)
        self._internal: BufferCall | None = None
        self._tau_wrench = np.zeros((self.n, NU))
        self._tau = np.zeros((self.n, NU))
        self._vc = np.zeros(3)
        self._grasp = grasp_parameters(s)
        self.nominal_parameters = np.tile(self.uvms.nominal_parameters(), (self.n, 1))
        self.nominal_object_parameters = self.object.nominal_parameters()
        self.parameters = np.zeros((self.n, NP))
        self.object_parameters = np.zeros(self.object.parameter_count)
        self.currents = Currents(self.uvms.params.currents[s.current], 1)
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
        and ``mismatch`` (``uvms_env.task.conditions``)."""
        s = self.scenario
        rng = np.random.default_rng(seed if seed is not None else s.seed)
        self.parameters, self.object_parameters = draw_truth_parameters(
            s, self.nominal_parameters, self.nominal_object_parameters, rng, mismatch
        )
        self.currents.reset([0], [rng], [self.uvms.params.currents[current or s.current]])
        self.set_state(s.initial_q, np.zeros((self.n, NQ)), s.object_start, np.zeros(6))
        self.t = 0.0
        return self.state

    def step(self, tau: np.ndarray, current: np.ndarray | None = None) -> StepInfo:
        """Advance one control period with inputs ``tau`` (N, 8), saturated at the limits;
        ``current`` (3,): this period's current velocity instead of the drawn one (replays)."""
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.n, NU):
            raise ValueError(f"tau must have shape ({self.n}, {NU}), got {tau.shape}")
        if not np.isfinite(tau.sum()):  # one reduction: NaN and inf survive a sum
            bad = np.argwhere(~np.isfinite(tau))[0]
            raise ValueError(f"tau contains NaN or inf (robot {bad[0]}, input {bad[1]})")
        saturated = np.abs(tau) > self.tau_max
        self.advance(tau, current)
        return StepInfo(self._tau.copy(), saturated, self._vc.copy())

    def advance(self, tau: np.ndarray, current: np.ndarray | None = None) -> None:
        """``step`` on inputs already checked (finite float64 (N, 8)), without its record:
        for a caller that checks them itself, the environment's adapter. The period is one
        compiled call; only a period it integrated inaccurately goes on to the refinement in
        halves."""
        # clip(tau) for finite tau, without np.clip's dispatch (a hot path)
        np.minimum(np.maximum(tau, self._tau_min, out=self._tau), self.tau_max, out=self._tau)
        period = self.scenario.period
        if current is None:
            drawn = self.currents.step(period)
            self._vc[:] = 0.0 if drawn is None else drawn[0]
        else:
            self._vc[:] = current
        x_next, drift, error = self._period(self._x, period)
        ok = self.control.accurate(drift, error, x_next)
        if not ok[0]:
            x_next, ok = self.control.refine(self._evaluate, self._ids, self._x_column, period)
            self.refinements += 1
        code = self.control.verdict(ok, x_next)[0]
        if code != OK:
            raise SimulationDiverged(self._refusal(code, x_next[:, 0]))
        self._x[:] = x_next[:, 0]
        self.t += period

    def _period(self, x: np.ndarray, h: float) -> tuple[np.ndarray, ...]:
        """The compiled period step of length ``h`` from ``x`` under the inputs set:
        (x_next, drift, error) as (element, 1) views of its buffers."""
        self._h[0] = h
        self._compiled_step()(
            x, self._tau, self._vc, self.parameters, self.object_parameters, self._grasp, self._h
        )
        return self._outputs

    def _compiled_step(self) -> BufferCall:
        """The compiled period step (``chain.step``), compiled and bound at first use."""
        if self._step is None:
            self._step = BufferCall(chain_of_capacity(*self._chain_args)[1])
            # the call's state, drift (N, 12) and error (N, 6) as (element, 1) views
            self._outputs = tuple(out.reshape(-1, 1) for out in self._step.outputs)
            self._drift = self._step.outputs[1]
        return self._step

    def _evaluate(self, ids: object, x0: np.ndarray, h: float) -> tuple[np.ndarray, ...]:
        """A refined part (``uvms_env.sim.period.Evaluate``): part ``h`` from ``x0``
        (nx, 1); its state is copied out, the next part's call rewrites the buffers."""
        self._x_part[:] = x0[:, 0]
        x_next, drift, error = self._period(self._x_part, h)
        return x_next.copy(), drift, error

    @property
    def last_drift(self) -> float:
        """Largest pose drift (m, rad) before the projection in the last compiled call."""
        return float(np.abs(self._drift[:, :6]).max())

    def _refusal(self, code: int, x: np.ndarray) -> str:
        """Why the period was refused: ``x`` is where the integration stopped (the start
        of the part that failed) or, beyond the envelope, the period's end."""
        where = f"the simulation diverged at t = {self.t:.2f} s: "
        if code == ENVELOPE:
            kind, value = envelope_excess(x, self.n)
            return (
                where + f"the {kind} speed {value:.3g} is beyond the model's envelope "
                f"({SPEED_LIMITS[kind]})"
            )
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
        return where + text

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
            s = self.scenario
            self._internal = BufferCall(
                _internal_wrench_function(self.n, self.object.capacity, s.period, s.substeps)
            )
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

    def wrench_inputs(self) -> tuple[np.ndarray, ...]:
        """The internal wrench's inputs but the grasp, as the last period left them (the
        state after it, its applied inputs and current, the truth parameters): for a
        kernel that samples the wrench with the rest of the step
        (``uvms_env.task.team_kernel``, ``chain`` = ``chain_key``)."""
        return self._x, self._tau, self._vc, self.parameters, self.object_parameters

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
