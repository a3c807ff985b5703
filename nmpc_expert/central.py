"""The centralized NMPC: one optimal control problem over the whole team's inputs.

The ladder's full-information reference (docs/expert.md, "Full-information reference"): a
team policy (``uvms_env.team_policy``) that reads the global state and decides the N x 8 normalized
inputs of every robot at once. What it has that no robot of the distributed expert has:
the exact coupled team-and-object model and the internal (squeeze) wrench.

    team = CentralNMPC(scenario)        # or make_central_policy()(scenario)
    team.reset()
    actions = team.act(env.state())     # (N, 8) in [-1, 1]
    team.stats                          # solve_time_ms, status, fallbacks, squeeze_rms, ...

The OCP is the distributed expert's (``ocp``) over the team, with ``central_rti``'s cost
and constraints, the model object handed to it (``team_model.TeamModel``) and one
real-time iteration per period; a failed solve never raises (a counted fallback). Not
modelled: the current, parameter mismatch and sensor noise; what they do is estimated
from the global state sequence as offset-free MPC does (``DISTURBANCE_GAIN``) and the
expert's goal integral removes what is left at the goal. Reference: docs/expert.md,
"Full-information reference".

May import: numpy, ``uvms_env`` and this package (``central_rti``, ``team_model``,
``policy``, ``reference``, ``settings``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from nmpc_expert.central_rti import CentralRTI
from nmpc_expert.local_controller import controller_weights, local_parameters, waypoint_index
from nmpc_expert.reference import GoalIntegral, HorizonReference
from nmpc_expert.settings import NMPCSettings
from nmpc_expert.team_model import TeamModel
from uvms_env.dynamics import NQ, NU
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.env.options import state_structure
from uvms_env.navigation import task_navigator
from uvms_env.policy import AgentSpec
from uvms_env.scenarios import Scenario
from uvms_env.team_policy import FULL_INFORMATION, TeamPolicyFactory

# Weight of the squared internal wrench per interval (per N^2 and (N m)^2). The input
# weight R = 0.3 per normalized input squared makes 1 N of thrust (a tenth of a vehicle
# saturation) cost 0.003; at 0.01 a squeeze of 1 N costs three times that, so the plan
# trades thrust for squeeze without letting the squeeze dominate the tracking.
SQUEEZE_WEIGHT = 0.01
# Low-pass gain per period of the additive state disturbance (the one-period prediction
# error): 0.3 settles in ~10 periods (1.2 s), far faster than the current changes, while
# averaging the error's period-to-period jitter (contact of the closed chain, integrator).
DISTURBANCE_GAIN = 0.3


# [rad] the reference's goal-integral clip per Euler angle: with the team's torque in one
# plan its attitude offset at the goal stays within this (central_settings)
ATTITUDE_CLIP = 0.3


def central_settings(**changes: Any) -> NMPCSettings:
    """The centralized controller's settings: the paper's controller
    (``NMPCSettings.paper``: the expert's weights, horizon, constraint limits and
    back-offs; no disturbance observer, no input step bound, which answer the local
    model's error), then ``changes``. The tighter angular back-off is kept although the
    team model has no internal-wrench error to cover: the same constraints for both. The
    goal integral keeps its attitude clip at ``ATTITUDE_CLIP``: the distributed expert's
    wider one cost the reference 2 of 10 random N = 2 episodes (docs/expert.md, "Tuning
    record")."""
    changes = {"goal_integral_angle_limit": ATTITUDE_CLIP, **changes}
    return NMPCSettings.paper(**changes)  # type: ignore[arg-type]


class CentralNMPC:
    """Centralized NMPC of the whole team (see module docstring); a ``TeamPolicy``."""

    information = FULL_INFORMATION

    def __init__(
        self,
        scenario: Scenario,
        settings: NMPCSettings | None = None,
        squeeze_weight: float = SQUEEZE_WEIGHT,
        model: TeamModel | None = None,
    ) -> None:
        """``model``: the prediction model handed to the controller (a ``TeamModel`` of
        this team over the settings' horizon); None: the scenario's, nominal."""
        if not isinstance(scenario, Scenario):
            raise TypeError(f"CentralNMPC needs the Scenario, got {type(scenario).__name__}")
        s = self.settings = settings or central_settings()
        if abs(s.period - scenario.period) > 1e-12:
            raise ValueError(f"settings.period {s.period} != scenario period {scenario.period}")
        if not squeeze_weight >= 0:
            raise ValueError(f"squeeze_weight must be >= 0, got {squeeze_weight}")
        self.scenario = scenario
        self.n = n = scenario.n_agents
        self.horizon = s.horizon
        self.model = TeamModel(scenario, s.horizon) if model is None else model
        m = self.model
        if (m.n, m.horizon) != (n, s.horizon) or abs(m.period - s.period) > 1e-12:
            raise ValueError(
                f"the model is of {m.n} robots over {m.horizon} periods of {m.period} s; "
                f"the controller needs {n} robots over {s.horizon} periods of {s.period} s"
            )
        self.nx, self.nu = m.nx, m.nu
        self.squeeze_weight = float(squeeze_weight)
        theta = np.stack([local_parameters(AgentSpec.from_scenario(scenario, i)) for i in range(n)])
        self.solver = CentralRTI(m, theta, controller_weights(s), self.squeeze_weight)
        self.disturbance = self.solver.disturbance  # estimated here, predicted with there
        self._previous: tuple[np.ndarray, np.ndarray] | None = None
        self._structure = st = state_structure(n)
        o = st["object_pose"].start
        # Euler angles: each vehicle's q[3:6], the object pose's [3:6]
        self._angles = np.r_[[NQ * i + j for i in range(n) for j in (3, 4, 5)], o + 3, o + 4, o + 5]
        self.navigator = task_navigator(
            scenario.waypoints, scenario.workspace, scenario.obstacles, scenario.team_radius
        )
        self.reference = HorizonReference(
            self.navigator, s.horizon, s.period, s.attitude_from_waypoint
        )
        self.goal = GoalIntegral(s, scenario.waypoints)
        self._wp = np.ascontiguousarray(scenario.waypoints, dtype=float)
        self.stats: dict[str, Any] = {}
        self.fallbacks = 0
        self.decisions = 0

    # -- TeamPolicy ----------------------------------------------------------------------
    def reset(self) -> None:
        self.solver.reset()
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
            action, info = self._iterate(x0, index)
        except Exception as err:  # a failed solve must never stop the team
            self.fallbacks += 1
            status = f"fallback: {type(err).__name__}: {err}"
            action = self.solver.fallback(x0, self._hold(x0))
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

    def executed(self, actions: np.ndarray) -> None:
        """The team's inputs applied this period, (N, 8), where they differ from the last
        decision (a student's under DAgger): the disturbance estimate predicts from them."""
        if self._previous is not None:
            applied = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
            self._previous = (self._previous[0], applied.reshape(self._previous[1].shape))

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
        return x0, waypoint_index(self._wp, st[self._structure["waypoint"]], "state")

    def _estimate(self, x0: np.ndarray) -> None:
        """Filter the one-period prediction error into the additive disturbance."""
        if self._previous is None:
            return
        error = x0 - self.model.step(*self._previous)
        error[self._angles] = wrap_angle(error[self._angles])  # yaw may cross +-pi
        if np.all(np.isfinite(error)):  # a diverged prediction must not poison the plan
            self.disturbance += DISTURBANCE_GAIN * (error - self.disturbance)

    def _iterate(self, x0: np.ndarray, index: int) -> tuple[np.ndarray, dict[str, Any]]:
        """One real-time iteration from x0 towards the reference of waypoint ``index``."""
        solver = self.solver
        # no plan: it starts from the inputs that hold the team at rest where it is
        a_init = None if solver.has_plan else self._at_rest(x0)
        x_o = x0[self._structure["object_pose"]]
        xd, vd = self.reference(x_o, index)
        solver.xd[:] = xd + self.goal.shift(x_o, index)
        solver.vd[:] = vd
        return solver.step(x0, a_init)

    def _at_rest(self, x0: np.ndarray) -> np.ndarray:
        """Every robot's steady input (N, 8) at x0, at rest."""
        return self.solver.steady_inputs(x0[None], np.zeros((1, 6)))[0]

    def _hold(self, x0: np.ndarray) -> np.ndarray:
        """The fallback's input with no plan: ``_at_rest``, or zeros if even those cannot
        be computed (no input at all rather than a raise in the loop)."""
        try:
            return self._at_rest(x0)
        except Exception:
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
