"""The running tallies of K episodes that become their metrics when they end.

``Tally`` accumulates, as arrays of the namespace ``xp``, what ``uvms_env.task.metrics``
reports: the smallest clearance and manipulability, the largest grasp drift, the
violations per constraint kind, the control effort and the internal wrench's samples;
``results`` turns those of ended episodes into the metrics dicts (``episode_result``).

May import: numpy, ``uvms_env.dynamics.compiled`` and ``uvms_env.task`` (metrics,
team_rows).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.task.metrics import episode_result
from uvms_env.task.team_rows import CLEARANCE, GRASP_ERROR, MANIPULABILITY


class Tally(NamespacePickled):
    """Per environment (batch shape B): ``min_clearance``, ``min_manipulability``,
    ``grasp_drift``, ``effort``, ``wrench_sq``, ``wrench_samples`` and ``violations``
    B + (C,) for the C constraint kinds (the built-in ones, then the extra ones)."""

    def __init__(self, xp: Any, batch: tuple[int, ...], n_constraints: int) -> None:
        self.xp = xp
        self.batch = b = batch
        self.min_clearance = xp.zeros(b)
        self.min_manipulability = xp.zeros(b)
        self.grasp_drift = xp.zeros(b)
        self.violations = xp.zeros((*b, n_constraints), np.int64)
        self.effort = xp.zeros(b)
        self.wrench_sq = xp.zeros(b)
        self.wrench_samples = xp.zeros(b, np.int64)

    def reset(self, ids: Any) -> None:
        self.min_clearance[ids] = np.inf
        self.min_manipulability[ids] = np.inf
        self.grasp_drift[ids] = 0.0
        self.violations[ids] = 0
        self.effort[ids] = 0.0
        self.wrench_sq[ids] = 0.0
        self.wrench_samples[ids] = 0

    def observe(self, ids: Any, team: Any) -> None:
        """The state's extremes, from the team kernel's rows (T,) + B' of ``ids`` (its
        clearance is +inf in a scene without obstacles: absent ones count nowhere)."""
        xp = self.xp
        self.min_clearance[ids] = xp.minimum(self.min_clearance[ids], team[CLEARANCE])
        self.min_manipulability[ids] = xp.minimum(
            self.min_manipulability[ids], team[MANIPULABILITY]
        )
        self.grasp_drift[ids] = xp.maximum(self.grasp_drift[ids], team[GRASP_ERROR])

    def add_step(self, kinds: Any, effort: Any, sampled: Any, wrench_sq: Any) -> None:
        """One step of every environment: the kinds violated B + (C,), its control effort
        B, and the internal wrench where it was sampled (``wrench_sq`` None: not sampled)."""
        self.effort += effort
        self.violations += kinds
        if wrench_sq is not None:
            self.wrench_sq += wrench_sq
            self.wrench_samples += sampled

    def results(
        self,
        ids: Any,
        steps: Any,
        x_o: Any,
        goal: Any,
        success: Any,
        period: float,
        constraints: tuple[str, ...],
    ) -> list[dict[str, Any]]:
        """The metrics dicts of the episodes ``ids`` that ended after ``steps`` B' at poses
        ``x_o`` B' + (6,), with their goals B' + (6,) and ``success`` B'."""
        rows = [
            self.host(a)
            for a in (
                steps,
                x_o,
                goal,
                self.min_clearance[ids],
                self.min_manipulability[ids],
                self.violations[ids],
                self.wrench_sq[ids],
                self.wrench_samples[ids],
                self.effort[ids],
                self.grasp_drift[ids],
                success,
            )
        ]
        if not self.batch:  # one environment: a batch of one
            rows = [r[None] for r in rows]
        steps, pose, goal, clearance, manip, violations, wrench, samples, effort, drift, ok = rows
        return [
            episode_result(
                period,
                steps[j],
                pose[j].tolist(),
                goal[j].tolist(),
                bool(ok[j]),
                clearance[j],
                manip[j],
                violations[j].tolist(),
                wrench[j],
                samples[j],
                effort[j],
                drift[j],
                constraints,
            )
            for j in range(len(steps))
        ]
