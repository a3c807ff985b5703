"""The waypoint sequencing of K environments: the team's on the true object, each
robot's on its own estimate of it.

``Sequencing`` holds the waypoints of every environment and where each sequencer stands,
as arrays of the namespace ``xp`` (numpy, or CuPy); ``uvms_env.task.rules.Task`` calls it
at the points of an episode its docstring lists. The team's sequencer is the task's
(it moves the reward's potential and decides the goal); each robot's is what that robot
can know (its observation's waypoint and navigation twist). The team kernel advances
both (``uvms_env.task.team_kernel``); here is only where they stand.

May import: numpy, ``uvms_env.dynamics.compiled`` and ``uvms_env.task.team_rows``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.task.team_rows import ALL, TEAM_INPUT, TEAM_SEQUENCER


class Sequencing(NamespacePickled):
    """Waypoints B + (W, 6) (zeros beyond each environment's ``waypoint_count`` B), the
    ``goal`` B + (6,), the team's sequencer as the team kernel reads it, ``team``
    B + (5,) float64 (``TEAM_INPUT``: waypoint index, done flag, then the constants of the
    task's tests: ``tests`` = (attitude weight, position tolerance, attitude tolerance)),
    and each robot's sequencer as the team kernel reads and writes it, ``robots`` B + (N, 2)
    float64 (waypoint index, done flag; ``robot_index`` reads it)."""

    def __init__(
        self,
        xp: Any,
        batch: tuple[int, ...],
        n_agents: int,
        w_max: int,
        tests: tuple[float, float, float],
    ) -> None:
        self.xp = xp
        self.batch = b = batch
        self._rows = xp.arange(b[0]) if b else None
        self.waypoints = xp.zeros((*b, w_max, 6))
        self.waypoint_count = xp.ones(b, np.int64)
        self.goal = xp.zeros((*b, 6))
        self.team = xp.zeros((*b, TEAM_INPUT))
        self.team[..., 2:] = xp.asarray(tests, dtype=float)
        self.robots = xp.zeros((*b, n_agents, 2))

    def any(self, mask: Any) -> bool:
        """A host test of a mask of shape B (B = (): a numpy scalar, tested as one)."""
        return bool(mask.any()) if self.batch else bool(mask)

    @property
    def team_waypoint(self) -> Any:
        """B + (6,): the team's active waypoint."""
        return self._waypoint_at(ALL, self.team[..., 0].astype(np.int64))

    @property
    def robot_index(self) -> Any:
        """B + (N,) int64: each robot's active waypoint."""
        return self.robots[..., 0].astype(np.int64)

    def _waypoint_at(self, ids: Any, index: Any) -> Any:
        """The waypoints of environments ``ids`` at ``index`` (shape B')."""
        if not self.batch:
            return self.waypoints[index]
        return self.waypoints[self._rows[ids], index]

    def set_geometry(self, ids: Any, waypoints: Any, counts: Any) -> None:
        """Environments ``ids`` take these waypoints (B' + (W, 6), zeros beyond each one's
        ``counts`` B'): host or device arrays."""
        xp = self.xp
        self.waypoints[ids] = xp.asarray(waypoints)
        self.waypoint_count[ids] = xp.asarray(counts)
        self.goal[ids] = self._waypoint_at(ids, self.waypoint_count[ids] - 1)

    def reset(self, ids: Any) -> None:
        """Every robot of ``ids`` back to its first waypoint, the team's sequencer too."""
        self.robots[ids] = 0.0
        self.team[ids, :2] = 0.0

    def commit(self, ids: Any, team_rows: Any) -> None:
        """The team's sequencer of ``ids`` moves as the kernel's call whose team rows are
        ``team_rows`` (T,) + B' found (a kernel call alone does not move it)."""
        self.team[ids, :2] = team_rows[TEAM_SEQUENCER].T
