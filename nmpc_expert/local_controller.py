"""``NMPCPolicy``: the distributed NMPC of one robot behind the shared policy interface.

    policy = NMPCPolicy(AgentSpec.from_scenario(scenario, i))   # solver="rti" | "ipopt"
    policy.reset()
    action = policy.act(obs_i)    # (8,) normalized inputs in [-1, 1]
    policy.stats                  # solve_time_ms, iterations, status, fallbacks, ...

``LocalController``: what the expert shares with the safety filter (see there).

Built only from robot i's ``AgentSpec`` and fed only its own observation; nothing is
shared between instances except read-only compiled functions.

May import: numpy, casadi, ``uvms_env`` (dynamics, navigation, policy, robot.observation)
and this package. Never ``baselines``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from nmpc_expert.observation_reader import OBSERVATION_STRUCTURE, check_observation
from nmpc_expert.ocp import CONSTRAINT_NAMES, NC, WEIGHT_LAYOUT, ocp_functions, weight_vector
from nmpc_expert.reference import AttitudeSlew, GoalIntegral, HorizonReference
from nmpc_expert.rti import ExtraRows, RTISolver
from nmpc_expert.settings import LIBRARY_HORIZONS, NMPCSettings, controller_settings
from uvms_env.dynamics import NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.dynamics.local_model import NX, ModelParams
from uvms_env.dynamics.uvms import default_model
from uvms_env.navigation import WaypointNavigator, task_navigator
from uvms_env.policy import AgentSpec

SOLVERS = ("rti", "ipopt")
JOINT_POSITION_ROWS = [i for i, name in enumerate(CONSTRAINT_NAMES) if "joint_position" in name]
_BOUNDS = ("lower", "upper", "scale")  # the constraint bounds' parts of the weight vector


def navigator_for(spec: AgentSpec) -> WaypointNavigator:
    """The navigation reference every robot of the task uses (the environment's rule,
    ``uvms_env.navigation.task_navigator``), rebuilt from the robot's own spec."""
    return task_navigator(spec.waypoints, spec.workspace, spec.obstacles, spec.team_radius)


def local_parameters(spec: AgentSpec, piece_fraction: float = 0.0) -> np.ndarray:
    """theta of the robot's local model from its spec: its grasp, and the object it
    carries (``NMPCSettings.piece_fraction``): at 0 its load share of the whole object at
    the centroid (the paper's); above, with load share 1, what
    ``ObjectModel.carried_parameters`` blends of that and of the piece of the object
    nearest its grasp."""
    obj = ObjectModel(spec.object_shape, spec.object_size)
    if piece_fraction > 0:  # 0 keeps the paper's numbers to the bit (the same model)
        p_o = obj.carried_parameters(spec.grasp_offset, spec.load_share, piece_fraction)
        carried = 1.0, p_o
    else:
        carried = spec.load_share, obj.nominal_parameters()
    return ModelParams(spec.grasp_offset, spec.grasp_rotation, *carried).pack()


def object_capacity(spec: AgentSpec) -> int:
    """The strip capacity of the robot's object: which compiled library it uses (one for
    every object of a capacity, ``uvms_env.dynamics.payload``)."""
    return ObjectModel(spec.object_shape, spec.object_size).capacity


def default_settings(solver: str) -> NMPCSettings:
    """The observer controller with rti; the paper's with ipopt (its only one)."""
    return NMPCSettings() if solver == "rti" else NMPCSettings.paper()


def constraint_bounds(settings: NMPCSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, upper, scale) of the NC soft constraints, normalized by ``scale``."""
    b = settings.backoff
    v_lin, v_ang = settings.vehicle_speed
    limit = np.array(
        [v_lin] * 3
        + [v_ang] * 3
        + [settings.joint_speed] * 4
        + [settings.joint_position] * 4
        + [np.pi / 2 - settings.pitch_margin] * 2  # object and vehicle pitch
    )
    scale = np.concatenate([limit, [settings.manipulability_eps]])
    back = np.full(len(limit), b)
    back[3:10] = settings.angular_backoff
    upper = np.concatenate([back, [np.inf]])
    lower = np.concatenate([-back, [1.0 / b]])  # det >= eps / backoff
    return lower, upper, scale


def controller_weights(settings: NMPCSettings) -> np.ndarray:
    """The OCP's weight vector (``ocp.weight_vector``) of ``settings``: its tracking and
    input weights, slack penalties and constraint bounds (``constraint_bounds``)."""
    s = settings
    lower, upper, scale = constraint_bounds(s)
    l1, l2 = s.slack_l1 * np.ones(NC), s.slack_l2 * np.ones(NC)
    if s.joint_position_penalty is not None:
        l1[JOINT_POSITION_ROWS], l2[JOINT_POSITION_ROWS] = s.joint_position_penalty
    return weight_vector(
        s.q_x * np.ones(6),
        s.q_v * np.ones(6),
        s.p_x * np.ones(6),
        s.r_u * np.ones(NU),
        l1,
        l2,
        lower,
        upper,
        scale,
        s.input_reference == "steady_state",
    )


def waypoint_index(waypoints: np.ndarray, waypoint: np.ndarray, source: str) -> int:
    """Which of the mission's ``waypoints`` the active ``waypoint`` read from ``source`` (an
    observation, the team state) is: float32 values, so matched to 1e-3."""
    d = np.max(np.abs(waypoints - waypoint), axis=1)
    k = int(np.argmin(d))
    if d[k] > 1e-3:
        raise ValueError(
            f"{source} waypoint {np.round(waypoint, 3).tolist()} is not one of the "
            "mission's waypoints"
        )
    return k


class LocalController:
    """What the expert and the safety filter (``safety_filter``) share: one robot's local
    prediction model, its soft constraints with the rate-offset estimator, a solver over
    the horizon, the ``executed`` hook and the counters. Built only from the robot's
    ``AgentSpec``; ``_measure`` reads the robot's own observation."""

    def __init__(
        self,
        spec: AgentSpec,
        solver: str = "rti",
        settings: NMPCSettings | None = None,
        cost: tuple[np.ndarray, np.ndarray] | None = None,
        extra: ExtraRows | None = None,
        max_step: float | None = None,
    ) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        self.spec = spec
        self.settings = s = settings or default_settings(solver)
        if abs(s.period - spec.period) > 1e-12:
            raise ValueError(f"settings.period {s.period} != scenario period {spec.period}")
        self.theta = local_parameters(
            spec, s.piece_fraction_for(float(np.linalg.norm(spec.grasp_offset)))
        )
        self.funcs = ocp_functions(
            object_capacity(spec), s.horizon, s.period, s.substeps, LIBRARY_HORIZONS
        )
        self.weights = controller_weights(s)
        self._steady = BufferCall(self.funcs.steady_input)
        if solver == "rti":
            self.solver = RTISolver(
                self.funcs, self.theta, self.weights, cost=cost, extra=extra, max_step=max_step
            )
        else:
            if cost is not None or extra is not None or max_step is not None:
                raise ValueError("a fixed QP cost, extra rows or max_step need the rti solver")
            from nmpc_expert.ipopt_solver import IpoptSolver

            self.solver = IpoptSolver(self.funcs, self.theta, self.weights, s)
        self.solver_name = solver
        if s.disturbance_observer and solver != "rti":
            raise ValueError(
                "the disturbance observer needs the rti solver; for ipopt use "
                "NMPCSettings.paper() (disturbance_observer=False)"
            )
        # rate-offset estimator (settings.offset_gain): the speed bounds, shifted in place
        # in the solver's weight vector by the estimated prediction error
        lower, upper, scale = (self.solver.weights[WEIGHT_LAYOUT[k]] for k in _BOUNDS)
        self._bounds = (lower.copy(), upper.copy(), scale.copy())
        self._lower, self._upper = lower, upper  # views, shifted in place
        self.rate_offset = np.zeros(NX // 2)  # e, filtered one-step error of zeta
        # disturbance observer (settings.disturbance_observer): d, the velocity part of
        # the solver's additive disturbance (a view, updated in place), and sigma^2, the
        # moving average of the squared innovation behind the adaptive speed margins
        self.disturbance = (
            self.solver.disturbance[NX // 2 :] if solver == "rti" else np.zeros(NX // 2)
        )
        self.innovation_var = np.zeros(NX // 2)
        self.innovation = np.zeros(NX // 2)  # nu of the last measurement (0 before one)
        # its prior: the cold-start margin (settings.margin_initial), as a variance
        k = max(s.margin_gain, 1e-12)
        self._innovation_var0 = (s.margin_initial * scale[: NX // 2] / k) ** 2
        self.innovation_var[:] = self._innovation_var0
        self.decisions = 0
        if s.disturbance_observer:
            self._apply_margin()
        # anti-windup: each rate's actuating input (B's one-hot rows; none for roll and
        # pitch) and the input applied last period
        b = np.asarray(default_model().B)
        self._actuated = b.any(axis=1)
        self._input_of_rate = b.argmax(axis=1)
        self._applied: np.ndarray | None = None
        self._predicted_zeta: np.ndarray | None = None
        self._x0 = np.zeros(NX)
        self.stats: dict[str, Any] = {}
        self.fallbacks = 0

    def reset(self) -> None:
        self.solver.reset()
        self.rate_offset[:] = 0.0
        self.disturbance[:] = 0.0
        if self.solver_name == "rti":
            self.solver.input_offset[:] = 0.0
        self.innovation_var[:] = self._innovation_var0
        self.innovation[:] = 0.0
        self._lower[:], self._upper[:] = self._bounds[0], self._bounds[1]
        self.decisions = 0  # before the margin: its start floor counts the decisions
        if self.settings.disturbance_observer:
            self._apply_margin()
        self._applied = None
        self._predicted_zeta = None
        self.stats = {}
        self.fallbacks = 0

    def _measure(self, obs: np.ndarray) -> np.ndarray:
        """The checked observation (float64); the model state ``_x0`` = [q; zeta] from it,
        and the rate-offset estimate updated against the last one-step prediction."""
        o = check_observation(obs)
        st = OBSERVATION_STRUCTURE
        self._x0[: NX // 2] = o[st["q"]]
        self._x0[NX // 2 :] = o[st["zeta"]]
        if self.settings.disturbance_observer:
            self._update_disturbance()
        else:
            self._update_rate_offset()
        return o

    def _hold(self) -> np.ndarray:
        """The nominal input that holds the robot (and its share of the object) at rest."""
        return self._steady(self._x0, self.theta, np.zeros(6))[0].ravel()

    def executed(self, action: np.ndarray) -> None:
        """The input actually applied after the last ``act``, when another policy drove
        (DAgger rollouts, a filter's correction). The one-step prediction that feeds the
        rate-offset estimator is corrected to first order, zeta_1 += Gamma_0 (a_applied -
        a_planned), so the estimator keeps measuring model error, not the other policy's
        choice. Only the RTI solver has Gamma_0 at hand; with IPOPT the prediction is
        dropped instead (the estimate holds for one period)."""
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (NU,) or not np.all(np.isfinite(a)):
            raise ValueError(f"executed action must be {NU} finite numbers, got {a.shape}")
        self._applied = np.clip(a, -1.0, 1.0)
        if self._predicted_zeta is None:
            return
        gain = self.solver.input_sensitivity() if self.solver_name == "rti" else None
        if gain is None:
            self._predicted_zeta = None
            return
        delta = np.clip(a, -1.0, 1.0) - self.solver.abar[0]
        self._predicted_zeta = self._predicted_zeta + gain[NX // 2 :] @ delta

    def _update_rate_offset(self) -> None:
        """e <- e + L (zeta - zeta_pred - e), clipped; then bounds on the speed rows
        (the first 10 soft constraints, c = zeta) shift by -e: zeta_pred + e within limits."""
        s = self.settings
        if self._predicted_zeta is None or s.offset_gain == 0:
            return
        err = self._x0[NX // 2 :] - self._predicted_zeta
        self.innovation[:] = err
        self.rate_offset += s.offset_gain * (err - self.rate_offset)
        lower, upper, scale = self._bounds
        m = NX // 2
        shift = np.clip(self.rate_offset / scale[:m], -s.offset_limit, s.offset_limit)
        self._lower[:m] = lower[:m] - shift
        self._upper[:m] = upper[:m] - shift

    def _update_disturbance(self) -> None:
        """Disturbance observer: the innovation nu = zeta - zeta_pred (the prediction
        already holds d) is integrated, d <- d + L_d nu, clipped to ``observer_limit``
        speed limits; its moving RMS sigma tightens the speed bounds (the first 10 soft
        constraints) by ``margin_gain`` sigma, at most ``margin_limit`` of each limit."""
        s = self.settings
        if self._predicted_zeta is None:
            return
        m = NX // 2
        nu = self._x0[m:] - self._predicted_zeta
        self.innovation[:] = nu
        scale = self._bounds[2]
        limit = s.observer_limit * scale[:m]
        step = s.observer_gain * nu
        if s.observer_anti_windup and self._applied is not None:
            # anti-windup: where the rate's input was saturated and the error asks for
            # more of it, the model's input gain is what is wrong (the teammates hold the
            # joint), not a missing force: integrating would only wind the estimate up
            a = self._applied[self._input_of_rate]
            step[self._actuated & (np.abs(a) >= 1.0 - 1e-9) & (a * nu < 0)] = 0.0
        np.clip(self.disturbance + step, -limit, limit, out=self.disturbance)
        if s.observer_input_gain > 0:
            self._offset_input_reference()
        w = s.margin_forgetting
        self.innovation_var += w * (nu * nu - self.innovation_var)
        self._apply_margin()

    def _offset_input_reference(self) -> None:
        """The steady-state input reference a_ss is the nominal model's; shift it by the
        input that cancels ``observer_input_gain`` * d on the vehicle's linear rates in
        one period, Gamma_0[j, k] da_k = -g d_j (k the rate's thruster, Gamma_0 of the
        last linearization), clipped to ``observer_input_limit``; see the settings."""
        gain = self.solver.input_sensitivity()
        if gain is None:
            return
        s = self.settings
        m = NX // 2
        offset = self.solver.input_offset
        d = self._input_disturbance()
        limit = s.observer_input_limit
        for j in range(3):  # surge, sway, heave
            k = self._input_of_rate[j]
            if gain[m + j, k] > 1e-9:
                shift = -s.observer_input_gain * d[j] / gain[m + j, k]
                offset[k] = min(max(shift, -limit), limit)  # np.clip's, on one number

    def _input_disturbance(self) -> np.ndarray:
        """The estimate the steady-input shift counters: the robot's own (a talking
        expert, ``nmpc_expert.comm``, fuses its teammates' into it)."""
        return self.disturbance

    def _apply_margin(self) -> None:
        """Speed bounds tightened by min(k sigma, margin_limit), and at least the start
        floor (``NMPCSettings.start_margin``: that fraction of each bound) at this
        decision (observer controller)."""
        s = self.settings
        lower, upper, scale = self._bounds
        m = NX // 2
        margin = np.minimum(
            s.margin_gain * np.sqrt(self.innovation_var) / scale[:m], s.margin_limit
        )
        floor = s.start_floor(self.decisions * s.period)
        if floor > 0:
            np.maximum(margin, floor * upper[:m], out=margin)
        self._lower[:m] = lower[:m] + margin
        self._upper[:m] = upper[:m] - margin


class NMPCPolicy(LocalController):
    """Distributed NMPC of one robot (see module docstring)."""

    def __init__(
        self,
        spec: AgentSpec,
        solver: str = "rti",
        settings: NMPCSettings | None = None,
    ) -> None:
        s = settings or default_settings(solver)
        super().__init__(spec, solver, s, max_step=s.input_step)
        self.navigator = navigator_for(spec)
        self.reference = HorizonReference(
            self.navigator, s.horizon, s.period, s.attitude_from_waypoint
        )
        self._object_state = BufferCall(self.funcs.object_state)
        self.goal = GoalIntegral(s, spec.waypoints)
        self._wp = np.ascontiguousarray(spec.waypoints, dtype=float)
        self.slew = None
        if s.attitude_tip_speed > 0:
            radius = ObjectModel(spec.object_shape, spec.object_size).bounding_radius
            rate = s.attitude_tip_speed / radius
            # an object the navigation law's own attitude rate turns slowly enough at its
            # tip keeps the waypoint's attitude (the paper's reference)
            if rate < self.navigator.max_att_rate:
                self.slew = AttitudeSlew(rate, s.horizon, s.period)

    # -- Policy protocol -----------------------------------------------------------------
    def reset(self) -> None:
        super().reset()
        self.goal.reset()
        if self.slew is not None:
            self.slew.reset()

    def act(self, obs: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        o = self._measure(obs)
        index = waypoint_index(self._wp, o[OBSERVATION_STRUCTURE["waypoint"]], "observation")
        x_o, _ = self._object_state(self._x0, self.theta)
        xd, vd = self.reference(x_o, index)
        if self.slew is not None:
            self.slew.apply(xd, vd, x_o)
        self.solver.xd[:] = xd + self.goal.shift(x_o, index)
        self.solver.vd[:] = vd
        status, info = "ok", {}
        try:
            # the first guess of a cold start only: a plan's shift replaces it
            a_init = None
            if not self.solver.has_plan:
                a_init = self._steady(self._x0, self.theta, self.solver.vd[0])[0].ravel()
            action, info = self.solver.step(self._x0.copy(), a_init)
            # the plan's node 1 is the model's one-step prediction under the applied input
            self._predicted_zeta = self.solver.xbar[1, NX // 2 :].copy()
        except Exception as err:  # a failed solve must never stop the robot
            self.fallbacks += 1
            status = f"fallback: {type(err).__name__}: {err}"
            action = self.solver.fallback(self._x0, self._hold())
            self._predicted_zeta = None
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        self._applied = action
        if self.settings.input_step is not None:
            self.solver.a_prev = action.copy()  # the step bound's anchor (``executed``)
        self.decisions += 1
        elapsed = (time.perf_counter() - start) * 1e3
        scale_joint = self._bounds[2][6:10]
        self.stats = {
            "solve_time_ms": elapsed,
            "iterations": info.get("iterations", 0),
            "status": status if status != "ok" else info.get("status", "ok"),
            "fallbacks": self.fallbacks,
            "waypoint_index": index,
            "rate_offset_max": float(np.max(np.abs(self.rate_offset / self._bounds[2][:10]))),
            "disturbance_max": float(np.max(np.abs(self.disturbance / self._bounds[2][:10]))),
            "margin_max": float(np.max(self._bounds[1][:10] - self._upper[:10])),
            # what the prediction (the observer's estimate in it) missed of this period's
            # joint rates, in joint-speed limits: the error a robot plans its bounds with
            "innovation_joint_max": float(np.max(np.abs(self.innovation[6:] / scale_joint))),
            "slow": elapsed > self.settings.fallback_after_ms,
            **{k: v for k, v in info.items() if k not in ("iterations", "status")},
        }
        return action

    def executed(self, action: np.ndarray) -> None:
        super().executed(action)
        if self.settings.input_step is not None:  # the input applied anchors the step bound
            self.solver.a_prev = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1, 1)


def make_policy(
    solver: str = "rti", controller: str | None = None, **settings: Any
) -> Callable[[AgentSpec], NMPCPolicy]:
    """A ``PolicyFactory`` (AgentSpec -> policy) for evaluators, e.g.
    ``make_policy("rti", q_v=0.4)`` or ``make_policy(controller="paper")``; ``controller``:
    ``observer`` or ``paper`` (``settings.controller_settings``; None: ``observer`` with
    rti, ``paper`` with ipopt). Unknown setting names raise ValueError."""
    unknown = sorted(set(settings) - set(NMPCSettings.field_names()))
    if unknown:
        raise ValueError(f"unknown NMPC setting(s) {unknown}; known: {NMPCSettings.field_names()}")
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    cfg = controller_settings(
        controller or ("observer" if solver == "rti" else "paper"), **settings
    )

    def factory(spec: AgentSpec) -> NMPCPolicy:
        return NMPCPolicy(spec, solver=solver, settings=cfg)

    return factory
