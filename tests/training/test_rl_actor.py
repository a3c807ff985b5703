"""PPO's compiled decision (``baselines.networks.ppo_decision``) against SB3's own ``predict`` path:
the same inputs to 1e-5 for every prior setting and for the central critic's actor."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import uvms_env
from baselines.loaders.sb3_policy import SB3Policy
from uvms_env.policy import AgentSpec
from uvms_env.vector import VectorEnv
from uvms_env.vector.sb3 import VectorVecEnv

SETTINGS = {
    "plain": {},
    "residual_features_hold": {
        "action_mode": "residual",
        "observation_mode": "features",
        "residual_scale": 0.5,
        "hold_stiffness": 0.5,
        "hold_damping": 1.0,
    },
    "residual_raw": {"action_mode": "residual", "residual_scale": 1.5},
    "setpoint_features": {"action_mode": "setpoint", "observation_mode": "features"},
}


def _save_run(folder, model, venv, options: dict, rng: np.random.Generator) -> None:
    """A run folder with spread-out weights (a fresh actor's outputs are ~0.01) and
    normalization statistics, so that layers, normalization and clips all matter."""
    from stable_baselines3.common.vec_env import VecNormalize

    with torch.no_grad():
        for p in model.policy.parameters():
            p.copy_(torch.as_tensor(rng.normal(0.0, 0.4, p.shape), dtype=p.dtype))
    model.save(folder / "model.zip")
    norm = VecNormalize(venv, clip_obs=3.0)
    dim = venv.observation_space.shape[0]
    norm.obs_rms.mean = rng.normal(0.0, 0.5, dim)
    norm.obs_rms.var = rng.uniform(0.2, 4.0, dim)
    norm.save(str(folder / "vecnormalize.pkl"))
    (folder / "config.json").write_text(json.dumps({"overrides": options}))


def _observations(scenario: str, count: int) -> tuple[list[np.ndarray], AgentSpec]:
    env = uvms_env.parallel_env(scenario)
    obs, _ = env.reset(seed=5)
    rng = np.random.default_rng(3)
    seen = []
    for _ in range(count):
        seen.append(obs[env.possible_agents[0]].copy())
        obs, *_ = env.step({a: rng.uniform(-0.5, 0.5, 8).astype(np.float32) for a in env.agents})
    return seen, AgentSpec.from_scenario(env.scenario, 0)


def _compare(folder, scenario: str) -> np.ndarray:
    observations, spec = _observations(scenario, 40)
    fast = SB3Policy(spec, "ppo", folder)
    slow = SB3Policy(spec, "ppo", folder, compiled=False)
    assert fast.compiled and not slow.compiled
    got = np.array([fast.act(o) for o in observations])
    want = np.array([slow.act(o) for o in observations])
    np.testing.assert_allclose(got, want, atol=1e-5)
    return got


@pytest.mark.parametrize("setting", sorted(SETTINGS))
def test_compiled_ppo_decision_equals_predict(tmp_path, setting):
    from stable_baselines3 import PPO

    options = SETTINGS[setting]
    venv = VectorVecEnv(VectorEnv("short", 1, **options))
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, seed=0)
    _save_run(tmp_path, model, venv, options, np.random.default_rng(7))
    actions = _compare(tmp_path, "short")
    saturated = np.isclose(np.abs(actions), 1.0)
    assert saturated.any() and not saturated.all()  # both sides of the clip were exercised


def test_compiled_central_critic_actor_reads_its_own_observation(tmp_path, central_ppo):
    from baselines.rl.mappo import CentralStateVecEnv

    env = CentralStateVecEnv(VectorVecEnv(VectorEnv("short", 1), seed=0))
    model = central_ppo(env)
    _save_run(tmp_path, model, env, {}, np.random.default_rng(8))
    _compare(tmp_path, "short")


def test_compiled_decision_names_a_wrong_observation(tmp_path):
    from stable_baselines3 import PPO

    venv = VectorVecEnv(VectorEnv("short", 1))
    PPO("MlpPolicy", venv, n_steps=8, batch_size=16, seed=0).save(tmp_path / "model.zip")
    _, spec = _observations("short", 1)
    policy = SB3Policy(spec, "ppo", tmp_path)
    with pytest.raises(ValueError, match="shape"):
        policy.act(np.zeros(78, np.float32))
