"""The environment as RLlib sees it: ``uvms_env.parallel_env`` behind RLlib's
``ParallelPettingZooEnv``, with the episode seeds chosen here.

RLlib resets an environment with ``seed=None`` after its first episode, and the single
env then keeps its geometry: a runner of a seeded family (``random``, ``short``) would
train on one geometry forever. So every reset passes the episode seed chosen here, as
the SB3 trainer's ``geometry_pool`` does: with a pool of P, episode e of env runner w
(sub-env v of its V) has seed ``seed + (w V + v) P + e % P``: each sub-env cycles
through its own P geometries, which the single env builds once (an IPOPT solve,
~0.5 s) and keeps in memory (it keeps 32). Without a pool (``paper``) the seeds are
drawn from the sub-env's own stream. RLlib builds a runner's V sub-envs with one and the
same context (``vector_index`` 0), so v is the order in which this process built them.

May import: numpy, gymnasium, ray.rllib and ``uvms_env``; imported only where Ray is.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

ENV_NAME = "uvms_coop"
_BUILT = itertools.count()  # sub-envs built in this process (see module docstring)


class UVMSMultiAgentEnv(ParallelPettingZooEnv):
    """``config``: ``scenario``, ``overrides`` (env options), ``seed``, ``geometry_pool``
    (geometries per sub-env; None: seeds from a stream), ``envs_per_runner``; RLlib's
    ``EnvContext`` adds the runner's index."""

    def __init__(self, config: dict[str, Any]) -> None:
        import uvms_env

        worker = int(getattr(config, "worker_index", 0))
        per_runner = int(config.get("envs_per_runner", 1))
        vector = next(_BUILT) % per_runner
        seed = int(config.get("seed", 0))
        self._pool: int | None = config.get("geometry_pool")
        self._episodes = 0
        self._offset = seed + (worker * per_runner + vector) * (self._pool or 0)
        self._rng = np.random.default_rng((seed, worker, vector))
        # built on the first episode's seed: its reset finds that geometry already built
        self._upcoming = self._draw()
        env = uvms_env.parallel_env(
            scenario=config["scenario"], seed=self._upcoming, **config.get("overrides", {})
        )
        super().__init__(env)

    def _draw(self) -> int:
        if not self._pool:
            return int(self._rng.integers(2**31 - 1))
        self._episodes += 1
        return self._offset + (self._episodes - 1) % self._pool

    def _next_seed(self) -> int:
        seed, self._upcoming = self._upcoming, self._draw()
        return seed

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        del seed  # RLlib's seed repeats per runner; ours differ per runner and episode
        obs, infos = self.par_env.reset(seed=self._next_seed(), options=options)
        return obs, infos or {}


def make_env(config: dict[str, Any]) -> UVMSMultiAgentEnv:
    return UVMSMultiAgentEnv(config)
