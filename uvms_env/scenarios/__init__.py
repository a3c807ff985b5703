"""Scenarios: the paper's task and randomized families behind one validated config type.

``make(name, **overrides)`` builds a ``Scenario``; inconsistent input raises ValueError
naming the problem. ``current_within_reach(scenario)`` tells whether its ocean current
is slower than the team's top speed (``uvms_env.scenarios.reach``). May import: numpy,
scipy (in ``reach``, when called), ``uvms_env.models``, ``uvms_env.dynamics``,
``uvms_env.navigation``.
"""

from uvms_env.scenarios.config import CURRENT_PRESETS, Scenario, obstacle_distance
from uvms_env.scenarios.families import (
    COMMON_OVERRIDES,
    FAMILIES,
    SEEDED_FAMILIES,
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
    "make",
    "max_waypoints",
    "obstacle_distance",
    "replace",
    "team_top_speed",
]
