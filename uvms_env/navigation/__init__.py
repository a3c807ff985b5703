"""Navigation references for the carried object.

* :mod:`.field`: Rimon-Koditschek navigation function on the object position (sphere
  world: workspace ball, vertical cylinders, spheres, all inflated by the team radius),
  evaluated in log form; velocity reference ``min(v_max, K_NF |p - p_d|)`` along
  ``-grad phi``; CasADi version for MPC; empirical choice of ``k``.
* :mod:`.waypoints`: waypoint sequencing and the desired object twist
  ``[v_d; ZYX Euler-angle rates]``.
* :mod:`.task_navigator`: the task's sequencing tolerance and its rule for ``k``, one source
  for the environment and the expert.
* :mod:`.parametric`: the same twist with the scene as inputs, branch-free, so that
  environments of different geometries share one compiled (batched) function.

Dependencies: this package may import numpy and casadi only.
"""

from .field import (
    Cylinder,
    NavigationField,
    Obstacle,
    Sphere,
    Workspace,
    choose_k,
    descend,
    sample_free_points,
    wrap_angle,
)
from .parametric import (
    N_CYLINDERS,
    N_SPHERES,
    field_parameters,
    parametric_twist_function,
    parametric_velocity,
    twist_parameters,
)
from .task_navigator import (
    NAV_K_MAX,
    NAV_K_MIN,
    WAYPOINT_TOLERANCE,
    navigation_gain,
    task_navigator,
)
from .waypoints import WaypointNavigator, WaypointSequencer

__all__ = [
    "NAV_K_MAX",
    "NAV_K_MIN",
    "N_CYLINDERS",
    "N_SPHERES",
    "WAYPOINT_TOLERANCE",
    "Cylinder",
    "NavigationField",
    "Obstacle",
    "Sphere",
    "WaypointNavigator",
    "WaypointSequencer",
    "Workspace",
    "choose_k",
    "descend",
    "field_parameters",
    "navigation_gain",
    "parametric_twist_function",
    "parametric_velocity",
    "sample_free_points",
    "task_navigator",
    "twist_parameters",
    "wrap_angle",
]
