"""The environment as RLlib sees it: ``uvms_env.parallel_env`` behind RLlib's
``ParallelPettingZooEnv``, with the episode seeds chosen here.

RLlib resets an environment with ``seed=None`` after its first episode, and the single
env then keeps its geometry: a runner of a seeded family (``random``, ``short``) would
train on one geometry forever. So every reset passes the episode seed of the adapters'
one rule (``uvms_env.vector.seeding``): the K = W V sub-envs of W env runners (V each)
are copies k = (w - 1) V + v (the local runner, w = 0, counts as the first when there
are no remote ones), and episode e of copy k has seed ``seed + k + K e``, mod P with a
geometry pool of P. The single env builds each of its geometries once (an IPOPT solve,
~0.5 s) and keeps them in memory (it keeps 32). RLlib builds a runner's V sub-envs with
one and the same context (``vector_index`` 0), so v is the order in which this process
built them.

May import: gymnasium, ray.rllib and ``uvms_env``; imported only where Ray is.
"""

from __future__ import annotations

import itertools
from typing import Any

from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

from uvms_env.vector.seeding import episode_seed

ENV_NAME = "uvms_coop"
_BUILT = itertools.count()  # sub-envs built in this process (see module docstring)


class UVMSMultiAgentEnv(ParallelPettingZooEnv):
    """``config``: ``scenario``, ``overrides`` (env options), ``seed``, ``geometry_pool``
    (None: no pool), ``envs_per_runner``, ``num_env_runners``; RLlib's ``EnvContext`` adds
    the runner's index."""

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

    def _draw(self) -> int:
        self._episodes += 1
        return episode_seed(self._seed, self._copy, self._episodes - 1, self._copies, self._pool)

    def _next_seed(self) -> int:
        seed, self._upcoming = self._upcoming, self._draw()
        return seed

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        del seed  # RLlib's seed repeats per runner; ours differ per runner and episode
        obs, infos = self.par_env.reset(seed=self._next_seed(), options=options)
        return obs, infos or {}


def make_env(config: dict[str, Any]) -> UVMSMultiAgentEnv:
    return UVMSMultiAgentEnv(config)
