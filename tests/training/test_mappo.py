"""MAPPO's pieces: the central state beside each robot's observation, a critic that reads
it and an actor that does not."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.rl.mappo import CentralStateVecEnv
from uvms_env.vector import VectorEnv
from uvms_env.vector.sb3 import VectorVecEnv


def _central(max_cycles: int = 3) -> CentralStateVecEnv:
    return CentralStateVecEnv(VectorVecEnv(VectorEnv("short", 2, max_cycles=max_cycles), seed=4))


def test_each_robot_sees_its_own_observation_and_its_copys_state():
    env = _central()
    obs = env.reset()
    vec = env.venv.vector_env
    assert obs.shape == (4, env.local_dim + env.state_dim)
    local, state = obs[:, : env.local_dim], obs[:, env.local_dim :]
    np.testing.assert_array_equal(state, np.repeat(vec.state(), 2, axis=0))
    twin = VectorVecEnv(VectorEnv("short", 2, max_cycles=3), seed=4)
    np.testing.assert_array_equal(local, twin.reset())
    rng = np.random.default_rng(0)
    for _ in range(3):  # max_cycles 3: every copy ends on the last step
        env.step_async(rng.uniform(-1, 1, (4, 8)).astype(np.float32))
        obs, _, done, infos = env.step_wait()
    assert done.all()
    final = env.venv.last_infos["final_state"]
    for i in range(4):
        terminal = infos[i]["terminal_observation"]
        np.testing.assert_array_equal(terminal[env.local_dim :], final[i // 2])
        assert not np.array_equal(terminal[env.local_dim :], obs[i, env.local_dim :])


def test_actor_ignores_the_state_and_critic_reads_it(central_ppo):
    env = _central()
    model = central_ppo(env)
    model.learn(16)  # one update through the split networks
    obs = env.reset()
    other = obs.copy()
    other[:, env.local_dim :] = np.random.default_rng(1).normal(size=(4, env.state_dim)) * 5
    a1, _ = model.predict(obs, deterministic=True)
    a2, _ = model.predict(other, deterministic=True)
    np.testing.assert_array_equal(a1, a2)
    with torch.no_grad():
        v1 = model.policy.predict_values(torch.as_tensor(obs))
        v2 = model.policy.predict_values(torch.as_tensor(other))
    assert not torch.allclose(v1, v2)


def test_central_state_needs_the_batched_env():
    with pytest.raises(TypeError, match="VectorVecEnv"):
        CentralStateVecEnv(object())
