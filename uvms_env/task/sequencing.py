"""The waypoint sequencing of K environments: the team's on the true object, each
robot's on its own estimate of it.

``Sequencing`` holds the waypoints of every environment and where each sequencer stands,
as arrays of the namespace ``xp`` (numpy, or CuPy); ``uvms_env.task.rules.Task`` calls it
at the points of an episode its docstring lists. The team's sequencer is the task's
(it moves the reward's potential and decides the goal); each robot's is what that robot
can know (its observation's waypoint and navigation twist): the team kernel advances it
(``uvms_env.task.team_kernel``), here is only where it stands.

May import: numpy, ``uvms_env.dynamics.compiled``, ``uvms_env.navigation.task_navigator``
and ``uvms_env.task.team_rows``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.navigation.task_navigator import WAYPOINT_TOLERANCE
from uvms_env.task.team_rows import ALL


class Sequencing(NamespacePickled):
    """Waypoints B + (W, 6) (zeros beyond each environment's ``waypoint_count`` B), the
    team's active waypoint and the goal side by side in ``targets`` B + (2, 6) (one
    difference serves both), ``team_index``/``team_done`` B and each robot's sequencer as
    the team kernel reads and writes it, ``robots`` B + (N, 2) float64 (waypoint index,
    done flag; ``robot_index`` reads it).

    ``host_tests``: skip the rare branches (a waypoint near) with one host test; on a GPU
    that test would cost a synchronization, so there they always run."""

    def __init__(self, xp: Any, batch: tuple[int, ...], n_agents: int, w_max: int) -> None:
        self.xp = xp
        self.batch = b = batch
        self.host_tests = xp is np
        self._rows = xp.arange(b[0]) if b else None
        self.waypoints = xp.zeros((*b, w_max, 6))
        self.waypoint_count = xp.ones(b, np.int64)
        self.targets = xp.zeros((*b, 2, 6))
        self.has_obstacles = xp.zeros(b, bool)
        self.team_index = xp.zeros(b, np.int64)
        self.team_done = xp.zeros(b, bool)
        self.robots = xp.zeros((*b, n_agents, 2))

    def any(self, mask: Any) -> bool:
        """A host test of a mask of shape B (B = (): a numpy scalar, tested as one)."""
        return bool(mask.any()) if self.batch else bool(mask)

    @property
    def team_waypoint(self) -> Any:
        """B + (6,): the team's active waypoint (a view)."""
        return self.targets[..., 0, :]

    @property
    def robot_index(self) -> Any:
        """B + (N,) int64: each robot's active waypoint."""
        return self.robots[..., 0].astype(np.int64)

    @property
    def goal(self) -> Any:
        """B + (6,): the final waypoint (a view)."""
        return self.targets[..., 1, :]

    def _waypoint_at(self, ids: Any, index: Any) -> Any:
        """The waypoints of environments ``ids`` at ``index`` (shape B')."""
        if not self.batch:
            return self.waypoints[index]
        return self.waypoints[self._rows[ids], index]

    def set_geometry(self, ids: Any, waypoints: Any, counts: Any, has_obstacles: Any) -> None:
        """Environments ``ids`` take these waypoints (B' + (W, 6), zeros beyond each one's
        ``counts`` B') and obstacle flags B': host or device arrays."""
        xp = self.xp
        self.waypoints[ids] = xp.asarray(waypoints)
        self.waypoint_count[ids] = xp.asarray(counts)
        self.has_obstacles[ids] = xp.asarray(has_obstacles)
        self.goal[ids] = self._waypoint_at(ids, self.waypoint_count[ids] - 1)

    def reset(self, ids: Any) -> None:
        """Every robot of ``ids`` back to its first waypoint, the team's sequencer too."""
        self.robots[ids] = 0.0
        self.team_index[ids] = 0
        self.team_done[ids] = False

    def start(self, ids: Any, x_o: Any) -> None:
        """After a reset's first evaluation: the team's sequencer sees the true object."""
        self.team_waypoint[ids] = self.waypoints[ids][..., 0, :]
        self.advance_team(ids, self.distances(x_o, ids)[1][..., 0])

    def distances(self, x_o: Any, ids: Any = ALL) -> tuple[Any, Any]:
        """Pose differences B' + (2, 6) of the true object ``x_o`` B' + (6,) to the team's
        active waypoint and to the goal, and their position distances B' + (2,)."""
        d = x_o[..., None, :] - self.targets[ids]
        p = d[..., :3]
        return d, self.xp.sqrt((p * p).sum(axis=-1))

    def advance_team(self, ids: Any, dist: Any) -> Any:
        """The team's sequencer passes its waypoint where the true object is within the
        tolerance (``dist`` to the active one); returns where an intermediate waypoint was
        passed, or None when (numpy, checked on the host) none was near."""
        near = dist < WAYPOINT_TOLERANCE
        if self.host_tests and not self.any(near):
            return None
        near = near & ~self.team_done[ids]
        index = self.team_index[ids]
        last = index + 1 >= self.waypoint_count[ids]
        passed = near & ~last
        self.team_index[ids] = index = index + passed
        self.team_done[ids] = self.team_done[ids] | (near & last)
        self.team_waypoint[ids] = self._waypoint_at(ids, index)
        return passed
