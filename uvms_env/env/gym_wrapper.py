"""The centralized Gymnasium view of the environment, for single-agent algorithms: the
agents' observations and actions concatenated, the shared team reward. Centralized by
construction (a policy on it sees every robot): use the PettingZoo environment for
decentralized policies.

May import: numpy, gymnasium and ``uvms_env.env`` (parallel, infos).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from uvms_env.env.infos import CONSTRAINT_PREFIX
from uvms_env.env.parallel import CoopTransportEnv
from uvms_env.scenarios import Scenario


class CoopTransportGymEnv(gym.Env[np.ndarray, np.ndarray]):
    """Gymnasium ``uvms_env/CoopTransport-v1``: ``CoopTransportEnv`` seen as one agent.

    Observation ``Box(79 N,)`` float32, action ``Box(-1, 1, (8 N,), float32)``; agent i's
    part is ``[79 i, 79 (i + 1))`` and ``[8 i, 8 (i + 1))`` (with a channel, ``comm=``,
    each agent's part is its larger observation and action). ``info`` carries the team's
    keys of the agents' infos (``uvms_env.env.infos``: the reward's terms, ``episode_end``,
    ``diverged``, the metrics; the same keys at ``reset``), the robots' ``cost`` summed,
    and every agent's own info under ``"agents"``. Arguments: as ``CoopTransportEnv``.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": list(CoopTransportEnv.metadata["render_modes"]),
        "render_fps": CoopTransportEnv.metadata["render_fps"],
    }

    def __init__(
        self, scenario: str | Scenario = "paper", render_mode: str | None = None, **overrides: Any
    ) -> None:
        self.parallel = CoopTransportEnv(scenario, render_mode, **overrides)
        self.render_mode = render_mode
        agents = self.parallel.possible_agents
        obs = [self.parallel.observation_space(a) for a in agents]
        self.observation_space = spaces.Box(
            np.concatenate([o.low for o in obs]),
            np.concatenate([o.high for o in obs]),
            dtype=np.float32,
        )
        self.act_size = self.parallel.action_space(agents[0]).shape[0]  # 8 (+ the channel's)
        self.action_space = spaces.Box(-1.0, 1.0, (self.act_size * len(agents),), np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        obs, infos = self.parallel.reset(seed=seed, options=options)
        return self._flatten(obs), self._team_info(infos)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = np.asarray(action)
        if action.shape != self.action_space.shape:
            raise ValueError(
                f"action must have shape {self.action_space.shape}, got {action.shape}"
            )
        agents, m = self.parallel.possible_agents, self.act_size
        obs, rewards, terms, truncs, infos = self.parallel.step(
            {a: action[m * i : m * (i + 1)] for i, a in enumerate(agents)}
        )
        return (
            self._flatten(obs),
            float(rewards[agents[0]]),
            bool(terms[agents[0]]),
            bool(truncs[agents[0]]),
            self._team_info(infos),
        )

    def _team_info(self, infos: dict[str, dict[str, Any]]) -> dict[str, Any]:
        """The team's keys of the first agent's info (every key but its constraint values),
        the robots' ``cost`` summed, and every agent's own info under ``"agents"``."""
        first = infos[self.parallel.possible_agents[0]]
        info = {k: v for k, v in first.items() if not k.startswith(CONSTRAINT_PREFIX)}
        info["cost"] = sum(i["cost"] for i in infos.values())
        info["agents"] = infos
        return info

    def render(self) -> np.ndarray | None:
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()

    def _flatten(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([obs[a] for a in self.parallel.possible_agents])
