"""MAPPO with SB3's PPO: a centralized critic during training, a local actor always.

Each robot's sub-environment observation is extended by its copy's global state
(``VectorEnv.state()``): the critic reads the whole vector, the actor only its first
``local_dim`` numbers, so execution stays local (``SB3Policy`` passes zeros for the state;
a test checks that the actions do not depend on it). The "agent-specific global state" of
Yu et al. 2022. Written on SB3 because SB3 has no centralized critic; BenchMARL's MAPPO
(``--library benchmarl``) has its own, on one team size per run, and this one reads a
padded state over several. Reference: docs/rl.md.

May import: numpy, torch, gymnasium, stable-baselines3, ``uvms_env.dynamics`` (sizes) and
``uvms_env.vector``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn
from torch import nn

from uvms_env.dynamics import NQ
from uvms_env.vector.sb3 import VectorVecEnv


class CentralStateVecEnv(VecEnvWrapper):
    """Each robot sub-environment's observation followed by its copy's global state
    (``terminal_observation`` too, with the ended episode's last state).

    ``max_agents``: the state padded to a team of that size, so that teams of every size
    up to it give the critic one layout (runs over several team sizes): every robot's q
    and zeta padded with zeros to ``max_agents`` robots, the object, waypoint and time, and
    a mask of ``max_agents`` numbers (1: a robot of the team)."""

    def __init__(self, venv: VectorVecEnv, max_agents: int | None = None) -> None:
        if not isinstance(venv, VectorVecEnv):
            raise TypeError(
                f"MAPPO's central state comes from the batched env (VectorVecEnv), "
                f"got {type(venv).__name__}"
            )
        n_agents = venv.n_agents
        if max_agents is not None and max_agents < n_agents:
            raise ValueError(f"max_agents {max_agents} is below the team size {n_agents}")
        self.max_agents = max_agents
        self.local_dim = int(venv.observation_space.shape[0])
        self.state_dim = int(venv.vector_env.state().shape[1])
        if max_agents is not None:
            robots = 2 * NQ * n_agents
            self.state_dim += (2 * NQ + 1) * max_agents - robots
        n = self.local_dim + self.state_dim
        space = spaces.Box(-np.inf, np.inf, (n,), np.float32)
        super().__init__(venv, observation_space=space)

    def _padded(self, state: np.ndarray) -> np.ndarray:
        """(K, 20 N + 19) states in the padded layout (``max_agents``), else as they are."""
        if self.max_agents is None:
            return state
        n, m, k = self.venv.n_agents, self.max_agents, len(state)
        q, zeta = state[:, : NQ * n], state[:, NQ * n : 2 * NQ * n]
        pad = np.zeros((k, NQ * (m - n)), np.float32)
        mask = np.zeros((k, m), np.float32)
        mask[:, :n] = 1.0
        return np.concatenate([q, pad, zeta, pad, state[:, 2 * NQ * n :], mask], axis=1)

    def _with_state(self, obs: np.ndarray, state: np.ndarray) -> np.ndarray:
        per_robot = np.repeat(self._padded(state), self.venv.n_agents, axis=0)  # k N + a
        return np.concatenate([obs, per_robot], axis=1, dtype=np.float32)

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        return self._with_state(obs, self.venv.vector_env.state())

    def step_wait(self) -> VecEnvStepReturn:
        obs, reward, done, infos = self.venv.step_wait()
        final_state = self.venv.last_infos["final_state"]
        n = self.venv.n_agents
        if done.any():
            final_state = self._padded(final_state)
        for i in np.flatnonzero(done).tolist():
            final = infos[i]["terminal_observation"]
            infos[i]["terminal_observation"] = np.concatenate(
                [final, final_state[i // n]], dtype=np.float32
            )
        return self._with_state(obs, self.venv.vector_env.state()), reward, done, infos


class SplitMlpExtractor(nn.Module):
    """The actor's MLP on the first ``local_dim`` features, the critic's on all of them
    (SB3's ``MlpExtractor`` gives both the same input)."""

    def __init__(self, local_dim: int, full_dim: int, net_arch: list[int], activation: type):
        super().__init__()

        def mlp(inputs: int) -> nn.Sequential:
            layers: list[nn.Module] = []
            for width in net_arch:
                layers += [nn.Linear(inputs, width), activation()]
                inputs = width
            return nn.Sequential(*layers)

        self.local_dim = local_dim
        self.policy_net, self.value_net = mlp(local_dim), mlp(full_dim)
        self.latent_dim_pi = self.latent_dim_vf = net_arch[-1] if net_arch else local_dim
        if not net_arch:
            raise ValueError("the central critic needs at least one hidden layer")

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features[..., : self.local_dim])

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class CentralCriticPolicy(ActorCriticPolicy):
    """``ActorCriticPolicy`` whose actor reads only the first ``local_dim`` observation
    numbers. ``net_arch``: one list of hidden widths for both networks."""

    def __init__(self, *args: Any, local_dim: int, **kwargs: Any) -> None:
        self.local_dim = int(local_dim)
        kwargs["share_features_extractor"] = False
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        arch = self.net_arch if isinstance(self.net_arch, list) else self.net_arch["pi"]
        self.mlp_extractor = SplitMlpExtractor(
            self.local_dim, self.features_dim, list(arch), self.activation_fn
        ).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "local_dim": self.local_dim}
