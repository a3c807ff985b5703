"""The adapters' one seeding rule (``uvms_env.vector.seeding``): episode e of copy k of K
is reset with seed s + k + K e (mod P with a geometry pool), checked against single
environments reset with the seeds written out."""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from uvms_env.vector.seeding import copy_reset_seed

pytest.importorskip("stable_baselines3")


def test_the_rule_gives_every_copy_and_episode_its_own_seed():
    seeds = {copy_reset_seed(100, k, e, 3) for k in range(3) for e in range(50)}
    assert len(seeds) == 150 and min(seeds) == 100
    assert [copy_reset_seed(5, 1, e, 3, pool=4) for e in range(4)] == [2, 1, 0, 3]
    with pytest.raises(ValueError, match="copy"):
        copy_reset_seed(0, 3, 0, 3)


def _first_observations(seed: int) -> dict[str, np.ndarray]:
    obs, _ = uvms_env.parallel_env(scenario="short").reset(seed=seed)
    return obs


def test_the_sb3_adapter_starts_the_second_episode_on_the_rules_seed():
    """Two copies, 2-step episodes, a pool of 5: after the automatic reset, copy k's robots
    observe what a single env reset with seed (3 + k + 2) mod 5 observes."""
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv

    pool = 5
    inner = VectorEnv("short", 2, dtype="float64", max_cycles=2, geometry_pool=5, threads=1)
    venv = VectorVecEnv(inner, seed=3)
    obs = venv.reset()
    for k in range(2):
        first = _first_observations(copy_reset_seed(3, k, 0, 2, pool))
        np.testing.assert_allclose(obs[2 * k], first["uvms_0"], atol=1e-5)
    zero = np.zeros((4, 8), np.float32)
    for _ in range(2):
        obs, _, done, _ = venv.step(zero)
    assert done.all()
    for k in range(2):
        second = _first_observations(copy_reset_seed(3, k, 1, 2, pool))
        np.testing.assert_allclose(obs[2 * k + 1], second["uvms_1"], atol=1e-5)
    venv.close()
