"""Each robot's local observation: its layout, its sensor noise and how it is built.

A robot observes only what it measures itself (its own q and zeta, with noise) and what
it knows before the task (the scenario's waypoints and obstacles, its grasp and load
share). Everything about the object is its own estimate, derived from its own measured
kinematics and its known grasp; no other robot's data and no contact force enters.

``OBSERVATION_FIELDS`` is the one source of the layout: ``observation_structure``
(name -> slice) is generated from it, and a test checks the environment's docstring
table against it. The NMPC expert reads observations through these names.

May import: numpy, ``uvms_env.navigation`` and ``uvms_env.scenarios`` (types).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from uvms_env.navigation import WaypointNavigator, task_navigator

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario


OBSERVED_OBSTACLES = 3
FAR_OBSTACLE = (100.0, 100.0, 0.0, 0.0, 0.0)  # padding when fewer obstacles exist


@dataclass(frozen=True)
class ObservationField:
    name: str
    size: int
    meaning: str
    frame: str
    unit: str


OBSERVATION_FIELDS: tuple[ObservationField, ...] = (
    ObservationField(
        "q",
        10,
        "own generalized coordinates x y z phi theta psi q1..q4 (measured)",
        "NED, ZYX Euler",
        "m, rad",
    ),
    ObservationField(
        "zeta",
        10,
        "own velocities u v w p q r qd1..qd4 (measured)",
        "vehicle body; joints",
        "m/s, rad/s",
    ),
    ObservationField(
        "object_pose",
        6,
        "own estimate of the object pose x y z phi theta psi",
        "NED, ZYX Euler",
        "m, rad",
    ),
    ObservationField(
        "object_twist",
        6,
        "own estimate of the object twist p_dot_O, omega_O",
        "NED (inertial)",
        "m/s, rad/s",
    ),
    ObservationField(
        "waypoint",
        6,
        "active waypoint x y z phi theta psi (own sequencing)",
        "NED, ZYX Euler",
        "m, rad",
    ),
    ObservationField("goal", 6, "final waypoint x y z phi theta psi", "NED, ZYX Euler", "m, rad"),
    ObservationField(
        "nav_velocity",
        6,
        "navigation-function desired object twist: v_d, Euler-angle rates",
        "NED",
        "m/s, rad/s",
    ),
    ObservationField(
        "obstacles",
        OBSERVED_OBSTACLES * len(FAR_OBSTACLE),
        "3 nearest obstacles, each dx dy dz radius is_cylinder",
        "NED, from own object estimate",
        "m, m, m, m, 1",
    ),
    ObservationField("load_share", 1, "own load share c_i", "-", "1"),
    ObservationField("grasp_offset", 3, "own grasp offset l_i", "object frame", "m"),
    ObservationField(
        "grasp_rotation", 9, "own grasp rotation R_Oi, row-major", "object frame", "1"
    ),
    ObservationField("time_fraction", 1, "t / (max_cycles h)", "-", "1"),
)


def _structure() -> dict[str, slice]:
    out, start = {}, 0
    for f in OBSERVATION_FIELDS:
        out[f.name] = slice(start, start + f.size)
        start += f.size
    return out


OBSERVATION_STRUCTURE: dict[str, slice] = _structure()
OBSERVATION_SIZE = sum(f.size for f in OBSERVATION_FIELDS)
OBSERVATION_LAYOUT = tuple((f.name, f.size) for f in OBSERVATION_FIELDS)  # for the kernel


def observation_bounds() -> tuple[np.ndarray, np.ndarray]:
    """Low and high of the observation Box: unbounded except where bounds are exact."""
    s = OBSERVATION_STRUCTURE
    low = np.full(OBSERVATION_SIZE, -np.inf, dtype=np.float32)
    high = np.full(OBSERVATION_SIZE, np.inf, dtype=np.float32)
    low[s["grasp_rotation"]], high[s["grasp_rotation"]] = -1.0, 1.0
    low[s["load_share"]], high[s["load_share"]] = 0.0, 1.0
    low[s["time_fraction"]] = 0.0
    obstacles = np.arange(OBSERVATION_SIZE)[s["obstacles"]].reshape(-1, 5)
    low[obstacles[:, 3]] = 0.0  # radius
    low[obstacles[:, 4]], high[obstacles[:, 4]] = 0.0, 1.0  # is_cylinder
    return low, high


# Per-component standard deviation of the sensor noise at sensor_noise = 1 (the scenario
# scales it): position 2 cm, attitude and joint angles 0.01 rad; linear velocity 1 cm/s,
# angular velocity and joint rates 0.005 rad/s. Gaussian, independent per component.
NOISE_STD_Q = np.array([0.02] * 3 + [0.01] * 3 + [0.01] * 4)
NOISE_STD_ZETA = np.array([0.01] * 3 + [0.005] * 3 + [0.005] * 4)


def make_navigator(scenario: Scenario) -> WaypointNavigator:
    """The waypoint navigator every robot uses for a scenario (the task's rule:
    ``uvms_env.navigation.task_navigator``)."""
    return task_navigator(
        scenario.waypoints, scenario.workspace, scenario.obstacles, scenario.team_radius
    )
