"""Scenarios: the paper's task and randomized families behind one validated config type.

``make(name, **overrides)`` builds a ``Scenario``; inconsistent input raises ValueError
naming the problem. ``current_within_reach(scenario)`` tells whether its ocean current
is slower than the team's top speed (``uvms_env.scenarios.reach``); ``held_out`` whether
a scenario is the paper's task, which the random family never draws; ``object_key`` the
one number that names a scenario's object (``Scenario.object_key``).
May import: numpy, scipy (in ``reach``, when called), ``uvms_env.models``,
``uvms_env.dynamics``, ``uvms_env.navigation``.
"""

from uvms_env.dynamics.payload import object_key
from uvms_env.scenarios.config import CURRENT_PRESETS, Scenario, obstacle_distance
from uvms_env.scenarios.families import (
    COMMON_OVERRIDES,
    FAMILIES,
    SEEDED_FAMILIES,
    held_out,
    make,
    max_waypoints,
    replace,
)
from uvms_env.scenarios.reach import current_within_reach, team_top_speed

__all__ = [
    "COMMON_OVERRIDES",
    "CURRENT_PRESETS",
    "FAMILIES",
    "SEEDED_FAMILIES",
    "Scenario",
    "current_within_reach",
    "held_out",
    "make",
    "max_waypoints",
    "object_key",
    "obstacle_distance",
    "replace",
    "team_top_speed",
]
