"""Navigation references for the carried object.

* :mod:`.field`: Rimon-Koditschek navigation function on the object position (sphere
  world: workspace ball, vertical cylinders, spheres, all inflated by the team radius),
  evaluated in log form; velocity reference ``min(v_max, K_NF |p - p_d|)`` along
  ``-grad phi``; CasADi version for MPC; empirical choice of ``k``.
* :mod:`.waypoints`: waypoint sequencing and the desired object twist
  ``[v_d; ZYX Euler-angle rates]``.

Dependencies: this package may import numpy and casadi only.
"""

from .field import (
    Cylinder,
    NavigationField,
    Obstacle,
    Sphere,
    Workspace,
    attitude_rate,
    choose_k,
    descend,
    sample_free_points,
    wrap_angle,
)
from .waypoints import WaypointNavigator, WaypointSequencer, euler_rates_to_body_rates

__all__ = [
    "Cylinder",
    "NavigationField",
    "Obstacle",
    "Sphere",
    "WaypointNavigator",
    "WaypointSequencer",
    "Workspace",
    "attitude_rate",
    "choose_k",
    "descend",
    "euler_rates_to_body_rates",
    "sample_free_points",
    "wrap_angle",
]
