"""Scenarios: the paper's task and randomized families behind one validated config type.

``make(name, **overrides)`` builds a ``Scenario``; inconsistent input raises ValueError
naming the problem. May import: numpy, ``uvms_env.models``, ``uvms_env.dynamics``,
``uvms_env.navigation``.
"""

from uvms_env.scenarios.config import CURRENT_PRESETS, Scenario, obstacle_distance
from uvms_env.scenarios.families import COMMON_OVERRIDES, FAMILIES, make, replace

__all__ = [
    "COMMON_OVERRIDES",
    "CURRENT_PRESETS",
    "FAMILIES",
    "Scenario",
    "make",
    "obstacle_distance",
    "replace",
]
