"""Channel off: the environments play today's episodes bit for bit.

``tests/golden/comm_off_episodes_d4fcb8b.npz`` was recorded before the acoustic channel existed
(commit d4fcb8b) by ``single_episode`` and ``vector_episode`` below; with ``comm`` left
at its default (and with ``comm="off"``) every observation and reward must be equal.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import uvms_env
from uvms_env.vector import VectorEnv

DATA = Path(__file__).parent / "golden" / "comm_off_episodes_d4fcb8b.npz"
STEPS = 25
KEYWORDS = {"sensor_noise": 1.0, "mismatch": 0.1, "current": "mild"}


def single_episode(**comm) -> tuple[np.ndarray, np.ndarray]:
    env = uvms_env.parallel_env("paper", **KEYWORDS, **comm)
    obs, _ = env.reset(seed=7)
    rng = np.random.default_rng(1)
    out, rewards = [np.stack([obs[a] for a in env.possible_agents])], []
    for _ in range(STEPS):
        act = {a: rng.uniform(-0.3, 0.3, 8).astype(np.float32) for a in env.possible_agents}
        obs, rew, *_ = env.step(act)
        out.append(np.stack([obs[a] for a in env.possible_agents]))
        rewards.append(rew["uvms_0"])
    return np.stack(out), np.array(rewards)


def vector_episode(**comm) -> tuple[np.ndarray, np.ndarray]:
    venv = VectorEnv("random", num_envs=3, n_agents=3, **KEYWORDS, **comm)
    obs, _ = venv.reset(seed=11)
    rng = np.random.default_rng(2)
    out, rewards = [obs], []
    for _ in range(STEPS):
        obs, rew, *_ = venv.step(rng.uniform(-0.3, 0.3, (3, 3, 8)))
        out.append(obs)
        rewards.append(rew)
    return np.stack(out), np.stack(rewards)


def _comm_cases() -> list[dict]:
    try:
        from uvms_env.env.channel import ChannelSettings  # noqa: F401
    except ImportError:  # the tree the fixture was recorded on
        return [{}]
    return [{}, {"comm": None}, {"comm": "off"}]


@pytest.mark.parametrize("comm", _comm_cases())
def test_channel_off_plays_recorded_episodes(comm):
    ref = np.load(DATA)
    obs, rew = single_episode(**comm)
    assert np.array_equal(obs, ref["obs"]) and np.array_equal(rew, ref["reward"])
    vobs, vrew = vector_episode(**comm)
    assert np.array_equal(vobs, ref["vobs"]) and np.array_equal(vrew, ref["vreward"])
