"""Parameter sharing for SB3: every robot of every env copy is one sub-environment.

``ParallelVecEnv(factory, n_copies)`` builds ``n_copies`` PettingZoo parallel envs with N
agents each and exposes them as an SB3 ``VecEnv`` of ``n_copies * N`` sub-environments,
ordered copy-major then by ``possible_agents`` (copy 0's uvms_0, uvms_1, ..., copy 1's
uvms_0, ...). One shared policy then acts for every robot from its own observation: the
decentralized execution the task demands.

The team ends its episode together (shared termination); when a copy's episode ends,
each of its sub-environments reports done, its ``terminal_observation`` and
``TimeLimit.truncated`` in infos (SB3 conventions) and the copy is reset automatically.
SuperSuit's equivalent is slated for deprecation and breaks on current versions, so
this small adapter is ours. May import: numpy, gymnasium, stable-baselines3 and
``uvms_env.vector.seeding``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from uvms_env.vector.seeding import episode_seed


class ParallelVecEnv(VecEnv):
    """Episode ``e`` of copy ``k`` of K is reset with seed ``seed + k + K e``, the
    adapters' one rule (``uvms_env.vector.seeding``; for the seeded scenario families it
    also picks the geometry); ``seed(s)`` restarts that sequence from ``s`` at the next
    ``reset()``."""

    def __init__(self, factory: Callable[[int], Any], n_copies: int, seed: int = 0) -> None:
        """``factory(copy_index)`` returns a new PettingZoo ParallelEnv."""
        if n_copies < 1:
            raise ValueError(f"n_copies must be >= 1, got {n_copies}")
        self.envs = [factory(k) for k in range(n_copies)]
        self.agents = list(self.envs[0].possible_agents)
        for env in self.envs[1:]:
            if list(env.possible_agents) != self.agents:
                raise ValueError("every env copy must have the same agents")
        self.n_agents = len(self.agents)
        first = self.agents[0]
        super().__init__(
            n_copies * self.n_agents,
            self.envs[0].observation_space(first),
            self.envs[0].action_space(first),
        )
        self._seed = seed
        self._episodes = [0] * n_copies
        self._actions: np.ndarray | None = None
        self._obs = np.zeros((self.num_envs, *self.observation_space.shape), dtype=np.float32)

    def _slot(self, copy: int, agent_index: int) -> int:
        return copy * self.n_agents + agent_index

    def _reset_copy(self, copy: int) -> dict[str, np.ndarray]:
        seed = episode_seed(self._seed, copy, self._episodes[copy], len(self.envs))
        self._episodes[copy] += 1
        obs, infos = self.envs[copy].reset(seed=seed)
        for a, agent in enumerate(self.agents):
            self.reset_infos[self._slot(copy, a)] = dict(infos.get(agent, {}))
        return obs

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Restart the episode seed sequence from ``seed`` (used at the next ``reset``)."""
        if seed is not None:
            self._seed = int(seed)
            self._episodes = [0] * len(self.envs)
        k = len(self.envs)
        return [episode_seed(self._seed, c, 0, k) for c in range(k) for _ in self.agents]

    def reset(self) -> np.ndarray:
        for c in range(len(self.envs)):
            obs = self._reset_copy(c)
            for a, agent in enumerate(self.agents):
                self._obs[self._slot(c, a)] = obs[agent]
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait called without step_async")
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for c, env in enumerate(self.envs):
            acts = {agent: self._actions[self._slot(c, a)] for a, agent in enumerate(self.agents)}
            obs, rew, term, trunc, info = env.step(acts)
            episode_over = not env.agents
            for a, agent in enumerate(self.agents):
                i = self._slot(c, a)
                rewards[i] = rew.get(agent, 0.0)
                infos[i] = dict(info.get(agent, {}))
                done = bool(term.get(agent, False) or trunc.get(agent, False))
                if done and not episode_over:
                    raise RuntimeError(
                        f"agent {agent} ended its episode alone; ParallelVecEnv needs the team "
                        "to end together"
                    )
                dones[i] = episode_over
                if agent in obs:
                    self._obs[i] = obs[agent]
                if episode_over:
                    infos[i]["terminal_observation"] = self._obs[i].copy()
                    infos[i]["TimeLimit.truncated"] = bool(
                        trunc.get(agent, False) and not term.get(agent, False)
                    )
            if episode_over:
                new = self._reset_copy(c)
                for a, agent in enumerate(self.agents):
                    self._obs[self._slot(c, a)] = new[agent]
        self._actions = None
        return self._obs.copy(), rewards, dones, infos

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def _copies(self, indices: VecEnvIndices) -> Sequence[int]:
        idx = range(self.num_envs) if indices is None else np.atleast_1d(indices)
        return [int(i) // self.n_agents for i in idx]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.envs[c], attr_name) for c in self._copies(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for c in set(self._copies(indices)):
            setattr(self.envs[c], attr_name, value)

    def env_method(self, method_name: str, *args, indices: VecEnvIndices = None, **kwargs) -> list:
        return [getattr(self.envs[c], method_name)(*args, **kwargs) for c in self._copies(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._copies(indices)]
