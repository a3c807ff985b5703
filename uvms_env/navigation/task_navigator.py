"""The task's navigation rules, one source for the environment and the expert.

The sequencing tolerance every robot and the team use, and the rule that picks the
navigation function's exponent ``k`` for a scene: the environment builds each robot's
navigation twist with ``task_navigator`` and the expert rebuilds the same navigator from
what a robot knows a priori, through the same function.

May import: numpy and the sibling navigation modules.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np
from numpy.typing import ArrayLike

from .field import PAPER_K, Obstacle, Workspace, choose_k
from .parametric import parameter_row
from .waypoints import WaypointNavigator

# A robot (on its own object estimate) and the team (on the true object) pass a waypoint
# within this distance (m); attitude is not required at intermediate waypoints.
WAYPOINT_TOLERANCE = 0.3
# Navigation-function exponent: the paper's value, raised per scene when the empirical
# rule (choose_k) needs more to remove spurious minima, NAV_K_MAX when it finds none.
NAV_K_MIN = PAPER_K
NAV_K_MAX = 50.0


def navigation_gain(
    waypoints: ArrayLike, workspace: Workspace, obstacles: Sequence[Obstacle], team_radius: float
) -> float:
    """``k = max(NAV_K_MIN, choose_k(waypoint) for every waypoint)``, ``NAV_K_MAX`` where
    the rule finds none."""
    k = NAV_K_MIN
    for wp in np.asarray(waypoints, dtype=float):
        try:
            k = max(k, choose_k(wp[:3], workspace, obstacles, team_radius, k_max=NAV_K_MAX))
        except ValueError:
            k = NAV_K_MAX
    return k


def task_navigator(
    waypoints: ArrayLike, workspace: Workspace, obstacles: Sequence[Obstacle], team_radius: float
) -> WaypointNavigator:
    """The waypoint navigator of a scene (``navigation_gain``; other parameters the
    navigation module's defaults). Cached per scene: read-only once built."""
    wps = np.ascontiguousarray(waypoints, dtype=float)
    return _navigator(wps.tobytes(), len(wps), workspace, tuple(obstacles), float(team_radius))


@cache
def _navigator(
    waypoints: bytes, count: int, workspace: Workspace, obstacles: tuple, team_radius: float
) -> WaypointNavigator:
    wps = np.frombuffer(waypoints).reshape(count, 6)
    k = navigation_gain(wps, workspace, obstacles, team_radius)
    return WaypointNavigator(wps, workspace, obstacles, team_radius, k=k)


def waypoint_table(
    waypoints: ArrayLike, workspace: Workspace, obstacles: Sequence[Obstacle], team_radius: float
) -> np.ndarray:
    """(waypoints, NAV_PARAMETERS): each waypoint's ``parameter_row`` of the scene's
    ``task_navigator``, the table the team kernel sequences and navigates from."""
    nav = task_navigator(waypoints, workspace, obstacles, team_radius)
    return np.array([parameter_row(nav, i) for i in range(len(nav.sequencer))])
