"""The running tallies of K episodes that become their metrics when they end.

``Tally`` accumulates, as arrays of the namespace ``xp``, what ``uvms_env.task.metrics``
reports: the smallest clearance and manipulability, the largest grasp drift, the
violations and the graded excess per constraint kind, the control effort, the reward and
the internal wrench's samples;
``results`` turns those of ended episodes into the metrics dicts (``episode_result``).

May import: numpy, ``uvms_env.dynamics.compiled`` and ``uvms_env.task`` (metrics,
team_rows).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.task.metrics import EpisodeTallies, episode_result
from uvms_env.task.team_rows import CLEARANCE, GRASP_ERROR, MANIPULABILITY

#: The per-kind accumulators, B + (C,) each (``EpisodeTallies``' per-kind fields).
PER_KIND = ("violations", "excess_sum", "excess_max", "violated_robots")


class Tally(NamespacePickled):
    """Per environment (batch shape B): ``min_clearance``, ``min_manipulability``,
    ``grasp_drift``, ``effort``, ``wrench_sq``, ``wrench_samples``, ``reward`` and
    ``any_violated``, and B + (C,) for the C constraint kinds (the built-in ones, then the
    extra ones) ``violations``, ``excess_sum``, ``excess_max`` and ``violated_robots``
    (``uvms_env.task.metrics.EpisodeTallies``). ``n_agents``: robots per environment."""

    def __init__(self, xp: Any, batch: tuple[int, ...], n_constraints: int, n_agents: int) -> None:
        self.xp = xp
        self.batch = b = batch
        self.n_agents = n_agents
        self.min_clearance = xp.zeros(b)
        self.min_manipulability = xp.zeros(b)
        self.grasp_drift = xp.zeros(b)
        self.effort = xp.zeros(b)
        self.wrench_sq = xp.zeros(b)
        self.wrench_samples = xp.zeros(b, np.int64)
        self.reward = xp.zeros(b)
        self.any_violated = xp.zeros(b)
        self.violations = xp.zeros((*b, n_constraints), np.int64)
        self.excess_sum = xp.zeros((*b, n_constraints))
        self.excess_max = xp.zeros((*b, n_constraints))
        self.violated_robots = xp.zeros((*b, n_constraints))

    def reset(self, ids: Any) -> None:
        self.min_clearance[ids] = np.inf
        self.min_manipulability[ids] = np.inf
        for name in ("grasp_drift", "effort", "wrench_sq", "wrench_samples", "reward"):
            getattr(self, name)[ids] = 0
        self.any_violated[ids] = 0
        for name in PER_KIND:
            getattr(self, name)[ids] = 0

    def observe(self, ids: Any, team_rows: Any) -> None:
        """The state's extremes, from the team kernel's rows (T,) + B' of ``ids`` (its
        clearance is +inf in a scene without obstacles: absent ones count nowhere)."""
        xp = self.xp
        self.min_clearance[ids] = xp.minimum(self.min_clearance[ids], team_rows[CLEARANCE])
        self.min_manipulability[ids] = xp.minimum(
            self.min_manipulability[ids], team_rows[MANIPULABILITY]
        )
        self.grasp_drift[ids] = xp.maximum(self.grasp_drift[ids], team_rows[GRASP_ERROR])

    def add_step(
        self,
        kinds: Any,
        graded: tuple[Any, Any, Any, Any],
        effort: Any,
        sampled: Any,
        wrench_sq: Any,
    ) -> None:
        """One step of every environment: the kinds violated B + (C,); ``graded``, the
        robots' excess summed and its largest, the robots violating each kind B + (C,) and
        the robots violating any safety kind B; its control effort B, and the internal
        wrench where it was sampled (``wrench_sq`` None: not sampled)."""
        excess, largest, robots, any_violated = graded
        self.effort += effort
        self.violations += kinds
        self.excess_sum += excess
        self.xp.maximum(self.excess_max, largest, out=self.excess_max)
        self.violated_robots += robots
        self.any_violated += any_violated
        if wrench_sq is not None:
            self.wrench_sq += wrench_sq
            self.wrench_samples += sampled

    def add_reward(self, reward: Any) -> None:
        self.reward += reward

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
        fields = EpisodeTallies._fields
        rows = [self.host(a) for a in (steps, x_o, goal, success)]
        rows += [self.host(getattr(self, f)[ids]) for f in fields]
        if not self.batch:  # one environment: a batch of one
            rows = [r[None] for r in rows]
        steps, pose, goal, ok, *tallies = rows
        return [
            episode_result(
                period,
                self.n_agents,
                steps[j],
                pose[j].tolist(),
                goal[j].tolist(),
                bool(ok[j]),
                EpisodeTallies(*(t[j].tolist() for t in tallies)),
                constraints,
            )
            for j in range(len(steps))
        ]
