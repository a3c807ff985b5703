"""``SafetyFilter``: the expert's constraints around any policy (a predictive safety filter).

    policy = SafetyFilter(spec, inner)   # inner: a Policy for the same robot, or a factory
    action = policy.act(obs)             # the input closest to inner.act(obs) that the
                                         # robot's local model predicts to be safe
    policy.stats["intervened"]           # |a_out - a_prop| > tolerance this period

It is the expert's real-time iteration (``rti``) with the tracking cost replaced
(``RTISolver(cost=...)``) and u_0 linearized at a_prop (or, with ``max_input_step``, at
the allowed input nearest it), so a proposal predicted safe with the backup tail passes
unchanged; a failed QP falls back like the expert. Beyond the expert's rows it keeps the
workspace (``workspace``: a barrier at the plan's node 1). The problem, design,
input-step bound and what it does not cover: docs/safety-filter.md.

Built only from the robot's ``AgentSpec`` and fed only its own observation, like the
expert. May import: numpy, ``uvms_env`` and this package. Never ``baselines``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmpc_expert.filter_workspace_rows import WorkspaceRows
from nmpc_expert.local_controller import LocalController, local_parameters
from nmpc_expert.settings import FILTER_HORIZON, NMPCSettings
from uvms_env.dynamics import NU
from uvms_env.dynamics.local_model import NX
from uvms_env.policy import AgentSpec, Policy, PolicyFactory

# Why each constant below is as it is, with the measurements:
# docs/notes/2026-11-23-safety-filter-tuning.md.
# |rate offset| clip of the filter's estimator, in speed limits (the expert's:
# ``NMPCSettings.offset_limit``): the others' pull can exceed one limit.
FILTER_OFFSET_LIMIT = 2.0
# Workspace rows (``workspace``): a barrier on how fast a ball approaches the boundary,
# d/dt h <= -WORKSPACE_RATE (h + WORKSPACE_MARGIN), normalized by WORKSPACE_SCALE [m/s],
# with the expert's slack penalties. A barrier on the speed, not a bound on the position:
# a full input changes the team's speed by only a few cm/s per period, so position rows
# over the 0.36 s horizon could not be kept and their backup tail saturated. The rate
# asks for a deceleration of 0.5 v, within what the thrusters give at the vehicles' speed
# limit.
WORKSPACE_MARGIN = 0.2
WORKSPACE_RATE = 0.5
WORKSPACE_SCALE = 0.1


@dataclass
class _Decision:
    """What ``SafetyFilter.begin`` hands to ``finish``."""

    start: float
    proposed: float
    proposal: np.ndarray
    had_plan: bool
    backup: np.ndarray


class SafetyFilter(LocalController):
    """Minimal correction of ``policy``'s actions (see module docstring).

    ``input_weight``: W on the first input (a number or 8 numbers); ``regularization``:
    eps on the later inputs' change from the backup plan; ``tolerance``: a decision with
    max |a_out - a_prop| above it counts as an intervention; ``workspace``: add the
    workspace rows (``workspace_margin`` [m] inside the boundary). ``settings``: the expert's
    (constraints, back-offs, rate-offset estimator; default: the paper controller's
    settings, ``NMPCSettings.paper``, with ``horizon = FILTER_HORIZON`` and
    ``offset_limit = FILTER_OFFSET_LIMIT``; the disturbance observer is not used here).
    ``max_input_step``: bound delta on the input's change per period, along the plan too
    (module docstring); None: no bound (the default)."""

    def __init__(
        self,
        spec: AgentSpec,
        policy: Policy | PolicyFactory,
        settings: NMPCSettings | None = None,
        input_weight: float | np.ndarray = 1.0,
        regularization: float = 1e-3,
        tolerance: float = 1e-3,
        workspace: bool = True,
        workspace_margin: float = WORKSPACE_MARGIN,
        max_input_step: float | None = None,
    ) -> None:
        if not isinstance(policy, Policy):
            if not callable(policy):
                raise TypeError("policy must be a Policy or a factory(spec) -> Policy")
            policy = policy(spec)
        if not isinstance(policy, Policy):
            raise TypeError(f"{type(policy).__name__} does not implement reset(), act(obs), stats")
        weight = np.broadcast_to(np.asarray(input_weight, dtype=float), (NU,))
        if not (np.all(weight > 0) and regularization > 0 and tolerance >= 0):
            raise ValueError("input_weight and regularization must be > 0, tolerance >= 0")
        if max_input_step is not None and not max_input_step > 0:
            raise ValueError("max_input_step must be > 0 (or None)")
        settings = settings or NMPCSettings.paper(
            horizon=FILTER_HORIZON, offset_limit=FILTER_OFFSET_LIMIT
        )
        n = settings.horizon
        diag = np.concatenate([weight, np.full(NU * (n - 1), float(regularization))])
        # cost in the input steps da: u_0 = a_prop + da_0, u_k = ubar_k + da_k
        cost = (np.diag(2.0 * diag), np.zeros(NU * n))
        rows = None
        if workspace:
            rows = WorkspaceRows(
                spec.object_shape,
                spec.object_key,
                local_parameters(spec),
                (np.asarray(spec.workspace.center), spec.workspace.radius),
                workspace_margin,
                WORKSPACE_RATE,
                WORKSPACE_SCALE,
                settings.slack_l1,
                settings.slack_l2,
            )
        super().__init__(spec, "rti", settings, cost=cost, extra=rows, max_step=max_input_step)
        self.max_input_step = None if max_input_step is None else float(max_input_step)
        self._weight = weight
        self._cost_f = cost[1]  # the QP's linear term, updated in place (max_input_step)
        self.workspace_rows = rows
        if rows is not None:
            rows.zeta_offset = self.rate_offset  # the same array, updated in place
        self.policy = policy
        self.tolerance = float(tolerance)
        self.interventions = 0

    def reset(self) -> None:
        super().reset()
        self.policy.reset()
        self.interventions = 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.finish(self.begin(obs))

    def begin(self, obs: np.ndarray) -> _Decision:
        """The first half of ``act``: the proposal, the measurement and the plan shifted
        and linearized at the proposal, up to the QP builder's evaluation (which
        ``finish`` does, unless the solver's ``load_build`` got it from a batched call:
        ``nmpc_expert.filter_batch``)."""
        start = time.perf_counter()
        proposal = np.asarray(self.policy.act(obs), dtype=np.float64).reshape(-1)
        proposed = time.perf_counter()
        if proposal.shape != (NU,) or not np.all(np.isfinite(proposal)):
            raise ValueError(f"proposal must be {NU} finite numbers, got {proposal}")
        self._measure(obs)
        a_prop = np.clip(proposal, -1.0, 1.0)
        solver = self.solver
        a_lin = a_prop
        if self.max_input_step is not None:
            # linearize u_0 at the allowed input nearest the proposal (the QP's cost stays
            # ||u_0 - a_prop||^2_W: its linear term carries the offset a_lin - a_prop)
            if solver.a_prev is not None:
                d = self.max_input_step
                a_lin = np.clip(a_prop, solver.a_prev - d, solver.a_prev + d)
            self._cost_f[:NU] = 2.0 * self._weight * (a_lin - a_prop)
        had_plan = solver.has_plan
        solver.shift(self._x0.copy(), a_lin)  # with no plan yet, the tail holds a_lin
        backup = solver.abar[0].copy()
        solver.abar[0] = a_lin  # linearize u_0 at the proposal: da_0 = 0 passes it
        return _Decision(start, proposed, proposal, had_plan, backup)

    def finish(self, decision: _Decision) -> np.ndarray:
        """The second half of ``act``: the QP, its fallback, and the bookkeeping."""
        start, proposed, proposal = decision.start, decision.proposed, decision.proposal
        had_plan, backup = decision.had_plan, decision.backup
        solver = self.solver
        status, info = "ok", {}
        try:
            action, info = solver.iterate()
            self._predicted_zeta = solver.xbar[1, NX // 2 :].copy()
        except Exception as err:  # a failed solve must never stop the robot
            self.fallbacks += 1
            status = f"fallback: {type(err).__name__}: {err}"
            action = backup if had_plan else np.clip(self._hold(), -1.0, 1.0)
            if self.max_input_step is not None and solver.a_prev is not None:
                d = self.max_input_step
                action = np.clip(action, solver.a_prev - d, solver.a_prev + d)
            solver.abar[0] = action
            self._predicted_zeta = None
        if self.max_input_step is not None:
            solver.a_prev = action.copy()  # the input applied (``executed`` may replace it)
        deviation = float(np.max(np.abs(action - proposal)))
        intervened = deviation > self.tolerance
        self.interventions += intervened
        self.decisions += 1
        hook = getattr(self.policy, "executed", None)
        if hook is not None:  # a stateful inner policy follows the applied input
            hook(action)
        end = time.perf_counter()
        self.stats = {
            "solve_time_ms": (end - start) * 1e3,
            "proposal_time_ms": (proposed - start) * 1e3,
            "filter_time_ms": (end - proposed) * 1e3,
            "intervened": intervened,
            "intervention": deviation,  # max |a_out - a_prop| this period
            "interventions": self.interventions,
            "decisions": self.decisions,
            "iterations": info.get("iterations", 0),
            "status": status if status != "ok" else info.get("status", "ok"),
            "slack_max": info.get("slack_max", float("nan")),
            "fallbacks": self.fallbacks,
        }
        return action

    def executed(self, action: np.ndarray) -> None:
        """An outer driver applied ``action`` instead: the filter's estimator and the
        inner policy both follow it."""
        super().executed(action)
        if self.max_input_step is not None:
            self.solver.a_prev = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1, 1)
        hook = getattr(self.policy, "executed", None)
        if hook is not None:
            hook(action)


def make_filter(factory: PolicyFactory, **options: Any) -> Callable[[AgentSpec], SafetyFilter]:
    """A ``PolicyFactory`` wrapping ``factory``'s policies in a ``SafetyFilter``
    (``options``: its keyword arguments)."""

    def build(spec: AgentSpec) -> SafetyFilter:
        return SafetyFilter(spec, factory(spec), **options)

    return build
