"""A team policy as the robots' teacher: each robot's label is its row of the team's decision.

DAgger from a full-information teacher (``nmpc:central``, a ``uvms_env.team_policy``)
labels each robot's visited observation with what the team policy would have that robot
do in the visited state: one team decision per control period from ``env.state()``, row
``i`` for robot ``i``. The students still see only their own observations; only their
labels come from the global state (privileged-teacher distillation).

``TeamTeacher(factory, env)`` is a per-robot ``PolicyFactory`` for one episode of ``env``
(built after its reset, as ``uvms_env.episode.play`` does): robot 0's ``act`` takes the
period's team decision, the other robots read their rows of it, so the drivers' robot
order is the period's order. When a student's action was executed instead of a label,
the rollout tells that robot's slice (``executed``), and the team policy, when it has an
``executed`` hook (the centralized NMPC's disturbance estimate), hears the team's applied
inputs before its next decision: a stateful teacher follows the stream it labels.

May import: numpy and ``uvms_env``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.policy import AgentSpec
from uvms_env.team_policy import TeamPolicy, TeamPolicyFactory, check_team_actions


class TeamTeacher:
    """Per-robot label policies cut from one team policy on ``env`` (module docstring)."""

    def __init__(self, factory: TeamPolicyFactory, env: Any) -> None:
        self.factory, self.env = factory, env
        self.team: TeamPolicy | None = None
        self.decision: np.ndarray | None = None
        self.applied: np.ndarray | None = None

    def __call__(self, spec: AgentSpec) -> TeamSlice:
        if spec.index == 0:  # the first robot of an episode: a new team policy
            self.team = self.factory(self.env.scenario)
            self.decision = self.applied = None
        return TeamSlice(self, spec.index)

    def label(self, index: int) -> np.ndarray:
        """Robot ``index``'s row of this period's team decision (robot 0 takes it)."""
        if self.team is None:
            raise RuntimeError("TeamTeacher: robot 0's policy must be built first")
        if index == 0:
            hook = getattr(self.team, "executed", None)
            if hook is not None and self.applied is not None:
                hook(self.applied)
            decision = check_team_actions(self.team.act(self.env.state()), self.env.num_agents)
            self.decision, self.applied = decision, decision.copy()
        if self.decision is None:
            raise RuntimeError("TeamTeacher: robot 0 decides first in every period")
        return self.decision[index]

    def executed(self, index: int, action: np.ndarray) -> None:
        """Robot ``index`` applied ``action`` instead of its label this period."""
        if self.applied is not None:
            self.applied[index] = action


class TeamSlice:
    """One robot's view of a ``TeamTeacher``: a per-robot policy whose action is its row."""

    def __init__(self, teacher: TeamTeacher, index: int) -> None:
        self.teacher, self.index = teacher, index

    @property
    def stats(self) -> dict[str, Any]:
        team = self.teacher.team
        return dict(getattr(team, "stats", {}) or {})

    def reset(self) -> None:
        if self.index == 0 and self.teacher.team is not None:
            self.teacher.team.reset()

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.teacher.label(self.index)

    def executed(self, action: np.ndarray) -> None:
        self.teacher.executed(self.index, np.asarray(action, dtype=np.float64))
