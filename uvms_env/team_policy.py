"""The team-policy interface: one controller for the whole team, from the global state.

The one exception to the per-robot rule: a
full-information controller that sees ``env.state()`` (``uvms_env.env.options.
state_structure``) and returns every robot's normalized inputs at once, to measure the
price of decentralization (docs/evaluation.md, "Full-information rows"). It is kept apart
from the per-robot ``Policy`` (``uvms_env.policy``), whose contract stays: a robot sees
only its own observation.

    factory = TeamPolicyFactory(build, "nmpc:central")   # build(scenario) -> TeamPolicy
    team = factory(scenario)          # may know the whole scenario
    team.reset()
    actions = team.act(env.state())   # (N, 8) in [-1, 1]
    team.stats                        # the last decision's statistics

A team factory is a ``TeamPolicyFactory`` (not a bare callable), so a driver tells the two
kinds apart before building anything (``uvms_env.episode.play`` and ``play_team`` each
refuse the other's kind). A built team policy carries ``information = "full"``.

May import: numpy and ``uvms_env.scenarios`` (the type of what a factory is given).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from uvms_env.scenarios import Scenario

FULL_INFORMATION = "full"  # a team policy's ``information``; per-robot policies are "local"
LOCAL_INFORMATION = "local"


@runtime_checkable
class TeamPolicy(Protocol):
    """``reset()`` at the start of an episode, then ``act(state) -> (N, 8)`` normalized
    inputs once per control period; ``stats`` describes the last team decision;
    ``information`` is ``"full"``."""

    stats: dict[str, Any]
    information: str

    def reset(self) -> None: ...

    def act(self, state: np.ndarray) -> np.ndarray: ...


def is_team_policy(policy: object) -> bool:
    """Whether ``policy`` is a team policy (implements ``TeamPolicy`` and says so)."""
    return isinstance(policy, TeamPolicy) and policy.information == FULL_INFORMATION


@dataclass(frozen=True)
class TeamPolicyFactory:
    """Builds a team policy for a scenario; ``name`` labels it in errors and tables."""

    build: Callable[[Scenario], TeamPolicy]
    name: str = "team policy"

    def __call__(self, scenario: Scenario) -> TeamPolicy:
        if not isinstance(scenario, Scenario):
            raise TypeError(
                f"{self.name} is a team policy factory: it takes the Scenario, got "
                f"{type(scenario).__name__} (a per-robot driver passes AgentSpecs; play a "
                "team policy with uvms_env.episode.play_team)"
            )
        policy = self.build(scenario)
        if not is_team_policy(policy):
            raise TypeError(
                f"{self.name} built {type(policy).__name__}, which is not a team policy "
                "(reset(), act(state) -> (N, 8), stats, information = 'full')"
            )
        return policy


def check_team_actions(actions: Any, n: int) -> np.ndarray:
    """A team decision as (N, 8) float64, or a clear ValueError."""
    a = np.asarray(actions, dtype=np.float64)
    if a.shape != (n, 8):
        raise ValueError(f"a team policy must return ({n}, 8) actions, got shape {a.shape}")
    return a
