"""The policy interface shared by the NMPC expert and every baseline.

One controller per agent, built only from what that agent knows before the task (its
``AgentSpec``), mapping that agent's observation to its normalized action:

    policy = factory(spec)            # build once (may compile, load weights, ...)
    policy.reset()                    # new episode
    action = policy.act(obs)          # (8,) in [-1, 1]; obs: the agent's own observation
    policy.stats                      # dict of the last decision's statistics (may be empty)

A policy never sees another agent's observation, the global state or contact forces.
Under an acoustic channel the spec's ``comm`` holds the channel's settings, known before
the task like the robot's modem (docs/channel.md, "Policies, evaluation and training").
May import: numpy, ``uvms_env.scenarios`` and ``uvms_env.navigation`` (the map's types);
``uvms_env.robot.channel`` for type checking only (the env package imports this module).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from uvms_env.navigation import Cylinder, Sphere, Workspace
from uvms_env.scenarios import Scenario, object_key

if TYPE_CHECKING:
    from uvms_env.robot.channel import ChannelSettings


@dataclass(frozen=True, eq=False)
class AgentSpec:
    """What agent ``index`` knows a priori: scenario constants, its grasp, its load share,
    the static obstacle map and the waypoints. Nothing about the other robots' states."""

    index: int
    n_agents: int
    grasp_offset: np.ndarray  # (3,) l_i, object frame
    grasp_rotation: np.ndarray  # (3, 3) R_Oi
    load_share: float  # c_i
    object_shape: str
    object_size: float
    waypoints: np.ndarray  # (K, 6)
    obstacles: tuple[Cylinder | Sphere, ...]
    workspace: Workspace
    team_radius: float
    period: float
    success_pos_tol: float
    success_att_tol: float
    comm: ChannelSettings | None = None  # the acoustic channel; None: the silent team

    @property
    def object_key(self) -> float:
        """The object as one number, as the compiled functions name it (``object_key``):
        the ring's radius; 0 for the parameter file's bar, minus the length for another."""
        return object_key(self.object_shape, self.object_size)

    @staticmethod
    def from_scenario(
        scenario: Scenario, index: int, comm: ChannelSettings | None = None
    ) -> AgentSpec:
        if not 0 <= index < scenario.n_agents:
            raise ValueError(f"agent index {index} out of range for {scenario.n_agents} agents")
        return AgentSpec(
            index=index,
            n_agents=scenario.n_agents,
            grasp_offset=scenario.grasp_offsets[index].copy(),
            grasp_rotation=scenario.grasp_rotations[index].copy(),
            load_share=float(scenario.load_shares[index]),
            object_shape=scenario.object_shape,
            object_size=scenario.object_size,
            waypoints=scenario.waypoints.copy(),
            obstacles=scenario.obstacles,
            workspace=scenario.workspace,
            team_radius=scenario.team_radius,
            period=scenario.period,
            success_pos_tol=scenario.success_pos_tol,
            success_att_tol=scenario.success_att_tol,
            comm=comm,
        )


@runtime_checkable
class Policy(Protocol):
    """``reset()`` at the start of an episode, then ``act(obs) -> action`` (normalized,
    in [-1, 1]) once per control period; ``stats`` describes the last decision.

    A stateful policy may also define ``executed(action)``: a driver that applies some
    other action than the one returned (DAgger mixing, a safety filter) calls it after
    ``act``, so that the policy's memory follows what was actually applied."""

    stats: dict[str, Any]

    def reset(self) -> None: ...

    def act(self, obs: np.ndarray) -> np.ndarray: ...


PolicyFactory = Callable[[AgentSpec], Policy]
