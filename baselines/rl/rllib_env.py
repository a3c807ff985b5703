"""The environment as RLlib sees it: ``uvms_env.parallel_env`` behind RLlib's
``ParallelPettingZooEnv``, with the episode seeds chosen here.

RLlib resets an environment with ``seed=None`` after its first episode, and the single
env then keeps its geometry: a runner of a seeded family would train on one geometry
forever. So every reset passes the episode seed of the adapters' one rule
(``uvms_env.vector.seeding``): copy k = (w - 1) V + v of the K = W V sub-envs (the local
runner, w = 0, counts as the first when there are no remote ones), episode e seeded
``seed + k + K e``. RLlib builds a runner's V sub-envs with one context (``vector_index``
0), so v is the order in which this process built them.

With ``cost`` in the config, each step penalizes each robot's reward (PPO-Lagrangian);
the driver collects the ended episodes' costs (``take_episode_costs``) and sets the new
multiplier on every env (``set_multiplier``), each through ``each_env``.

May import: gymnasium, ray.rllib, numpy, ``baselines.lagrangian`` and ``uvms_env``; imported
only where Ray is.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

from baselines.lagrangian import CostSettings, Lagrangian, periods_left
from uvms_env.task.constraints import CONSTRAINTS
from uvms_env.vector.seeding import copy_reset_seed

ENV_NAME = "uvms_coop"  # the environment's name in RLlib's registry

_BUILT = itertools.count()  # sub-envs built in this process (see module docstring)


class UVMSMultiAgentEnv(ParallelPettingZooEnv):
    """``config``: ``scenario``, ``overrides`` (env options), ``seed``, ``geometry_pool``
    (None: no pool), ``envs_per_runner``, ``num_env_runners``, ``cost`` (None: none); RLlib's
    ``EnvContext`` adds the runner's index."""

    def __init__(self, config: dict[str, Any]) -> None:
        import uvms_env

        worker = int(getattr(config, "worker_index", 0))
        per_runner = int(config.get("envs_per_runner", 1))
        runners = max(1, int(config.get("num_env_runners", 0)))
        vector = next(_BUILT) % per_runner
        self._seed = int(config.get("seed", 0))
        self._pool: int | None = config.get("geometry_pool")
        self._episodes = 0
        self._copy = (max(worker, 1) - 1) * per_runner + vector
        self._copies = runners * per_runner
        # built on the first episode's seed: its reset finds that geometry already built
        self._upcoming = self._draw()
        env = uvms_env.parallel_env(
            scenario=config["scenario"], seed=self._upcoming, **config.get("overrides", {})
        )
        super().__init__(env)
        cost = config.get("cost")
        self.lagrangian = (
            Lagrangian(CostSettings(**cost), len(self.possible_agents)) if cost else None
        )
        # the team's return (the shared reward, unpenalized) and length of the running
        # episode, and those of the episodes ended since the driver last took them: what
        # every trainer records, where RLlib's own means sum the robots' penalized rewards
        self._return, self._length = 0.0, 0
        self._finished: list[tuple[float, int]] = []

    def _draw(self) -> int:
        self._episodes += 1
        return copy_reset_seed(self._seed, self._copy, self._episodes - 1, self._copies, self._pool)

    def _next_seed(self) -> int:
        seed, self._upcoming = self._upcoming, self._draw()
        return seed

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        del seed  # RLlib's seed repeats per runner; ours differ per runner and episode
        obs, infos = self.par_env.reset(seed=self._next_seed(), options=options)
        self._return, self._length = 0.0, 0
        if self.lagrangian is not None:
            self.lagrangian.reset()  # an episode cut short by a reset has no cost
        return obs, infos or {}

    def step(self, action_dict: dict):
        obs, rewards, terminated, truncated, infos = super().step(action_dict)
        # team episodes: every robot steps until the episode ends for all of them
        agents = self.possible_agents
        self._return += float(rewards[agents[0]])  # shared: the same for every robot
        self._length += 1
        if terminated[agents[0]] or truncated[agents[0]]:
            self._finished.append((self._return, self._length))
        if self.lagrangian is None:
            return obs, rewards, terminated, truncated, infos
        g = [[infos[a][f"constraint_{c}"] for c in CONSTRAINTS] for a in agents]
        count = [float(infos[a]["cost"]) for a in agents]
        done = np.array([bool(terminated[a] or truncated[a]) for a in agents])
        left = [periods_left(infos[a], self.par_env.max_cycles) for a in agents]
        cost = self.lagrangian.penalize(g, count, done, left)
        multiplier = self.lagrangian.multiplier
        for a, c in zip(agents, cost.tolist(), strict=True):
            infos[a]["constraint_cost"] = c
            rewards[a] = float(rewards[a]) - multiplier * c
        return obs, rewards, terminated, truncated, infos

    def set_multiplier(self, value: float) -> None:
        if self.lagrangian is not None:
            self.lagrangian.multiplier = float(value)

    def take_episodes(self) -> list[tuple[float, int]]:
        """(team return, length) of the episodes ended since the last call."""
        out, self._finished = self._finished, []
        return out

    def take_episode_costs(self) -> list[tuple[float, float]]:
        """The per-robot (cost, periods covered) of the episodes ended since the last call."""
        return self.lagrangian.take_finished() if self.lagrangian is not None else []


def make_env(config: dict[str, Any]) -> UVMSMultiAgentEnv:
    return UVMSMultiAgentEnv(config)


def runner_envs(runner: Any) -> list[UVMSMultiAgentEnv]:
    """An env runner's envs (none where it has no env: the driver's runner beside remote
    ones)."""
    vector = getattr(runner, "env", None)
    return [e.unwrapped for e in getattr(vector, "envs", [])]


def each_env(runner: Any, method: str, args: tuple[Any, ...] = ()) -> list[Any]:
    """``EnvRunnerGroup.foreach_env_runner`` (with ``functools.partial``): ``method`` of
    ``UVMSMultiAgentEnv`` called on each of the runner's envs with ``args``, the lists it
    returns joined (``take_episodes``, ``take_episode_costs``; ``set_multiplier``: [])."""
    return [x for env in runner_envs(runner) for x in getattr(env, method)(*args) or ()]
