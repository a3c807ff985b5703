"""A cheap deterministic scripted controller (a proportional pull of the object estimate
towards the active waypoint, arms idle) behind the policy interface: a stand-in expert
for the tests of ``python -m baselines.imitate`` without the NMPC
(``--expert experts.scripted:expert``). It is not meant to solve the task."""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.policy import AgentSpec
from uvms_env.robot.observation import OBSERVATION_STRUCTURE

GAIN = 0.5
_POSE = OBSERVATION_STRUCTURE["object_pose"]  # own estimate: x, y, z, phi, theta, psi
_WAYPOINT = OBSERVATION_STRUCTURE["waypoint"]
_Q = OBSERVATION_STRUCTURE["q"]  # vehicle pose (x, y, z, phi, theta, psi) and joints


class ScriptedPolicy:
    def __init__(self, spec: AgentSpec | None = None, gain: float = GAIN) -> None:
        self.spec = spec
        self.gain = gain
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        self.stats = {}

    def act(self, obs: np.ndarray) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float64)
        a = np.zeros(8)
        pose, waypoint, vehicle = o[_POSE], o[_WAYPOINT], o[_Q]
        a[:3] = self.gain * (waypoint[:3] - pose[:3])  # waypoint minus own object estimate
        a[3] = 0.2 * self.gain * wrap_angle(waypoint[5] - vehicle[5])  # waypoint vs vehicle yaw
        self.stats = {"solve_ms": 0.0, "iterations": 1, "fallbacks": 0}
        return np.clip(a, -1.0, 1.0).astype(np.float32)


def expert(spec: AgentSpec) -> ScriptedPolicy:
    """``PolicyFactory``: ``--expert experts.scripted:expert``."""
    return ScriptedPolicy(spec)
