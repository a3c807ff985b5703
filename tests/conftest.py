"""Shared fixtures: the models and the paper scenario are built once per test session."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.dynamics import ObjectModel
from uvms_env.scenarios import make
from uvms_env.scenarios.geometry import uvms_model


@pytest.fixture(scope="session")
def uvms():
    return uvms_model()


@pytest.fixture(scope="session")
def bar():
    return ObjectModel("bar")


@pytest.fixture(scope="session")
def paper():
    return make("paper")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def central_ppo():
    """A PPO model with the central critic (MAPPO) on a ``CentralStateVecEnv``."""

    def build(env, net_arch=(32, 32)):
        from stable_baselines3 import PPO

        from baselines.rl.mappo import CentralCriticPolicy

        kwargs = {"local_dim": env.local_dim, "net_arch": list(net_arch)}
        return PPO(CentralCriticPolicy, env, n_steps=8, batch_size=16, seed=0, policy_kwargs=kwargs)

    return build


@pytest.fixture(params=["numpy", "strict"])
def emulated_xp(request, monkeypatch):
    """The array namespace of the emulated CUDA device (``device="cpu"``): numpy, or the
    strict CuPy stand-in of ``strict_xp`` (arrays that refuse implicit host conversions,
    numpy operands and iteration as CuPy does), so that the backend's array code is checked
    as CuPy would run it."""
    if request.param == "strict":
        from strict_xp import xp

        from uvms_env.vector.kernels_emulated import EmulatedCudaFunction

        monkeypatch.setattr(EmulatedCudaFunction, "xp", xp)
    return request.param
