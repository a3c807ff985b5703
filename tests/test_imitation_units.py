"""Imitation-learning pieces that need no expert: BC, the network, the dataset format."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.spaces import Box

from baselines.imitation import bc, dataset
from baselines.imitation.network import ClonedPolicy, MLPPolicyNet


def test_bc_fits_a_known_linear_expert():
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4000, 12)).astype(np.float32) * 3 + 1
    w = rng.normal(size=(12, 8)) * 0.05
    act = np.tanh(obs @ w).astype(np.float32)  # inside (-1, 1), like normalized actions
    net, losses = bc.fit(obs, act, epochs=60, lr=3e-3, hidden=(64, 64), progress=False)
    assert losses[-1] < 3e-3 * act.var()  # R^2 > 0.997 on a smooth map
    import torch

    with torch.no_grad():
        pred = net(torch.as_tensor(obs[:100])).numpy()
    assert np.abs(pred - act[:100]).max() < 0.05


def test_saved_network_reproduces_its_decisions(tmp_path):
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(500, 79)).astype(np.float32)
    net, _ = bc.fit(obs, np.tanh(obs[:, :8]), epochs=2, progress=False)
    net.save(tmp_path / "policy.pt")
    policy = ClonedPolicy(spec=None, path=tmp_path / "policy.pt")  # type: ignore[arg-type]
    again = MLPPolicyNet.load(tmp_path / "policy.pt")
    import torch

    for o in obs[:20]:
        a = policy.act(o)
        assert a.shape == (8,) and np.all(np.abs(a) <= 1)
        with torch.no_grad():
            assert np.array_equal(a, again(torch.as_tensor(o[None]))[0].numpy())


def test_bc_rejects_mismatched_data():
    with pytest.raises(ValueError, match="must match"):
        bc.fit(np.zeros((10, 3)), np.zeros((9, 8)), progress=False)


def test_dataset_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    streams = []
    for k in range(3):
        s = dataset.AgentStream.start(rng.normal(size=79), seed=k)
        for t in range(5 + k):
            s.actions.append(rng.uniform(-1, 1, 8).astype(np.float32))
            s.observations.append(rng.normal(size=79).astype(np.float32))
            s.rewards.append(float(t))
            s.terminations.append(t == 4 + k)
            s.truncations.append(False)
            s.solve_ms.append(1.0 + t)
        streams.append(s)
    space_o = Box(-np.inf, np.inf, (79,), np.float32)
    space_a = Box(-1, 1, (8,), np.float32)
    dataset.write_dataset(streams, tmp_path, "roundtrip", space_o, space_a)
    obs, act, episodes = dataset.read_dataset(tmp_path, "roundtrip")
    assert len(episodes) == 3
    for s, ep in zip(streams, episodes, strict=True):
        assert np.array_equal(ep.observations, np.stack(s.observations))
        assert np.array_equal(ep.actions, np.stack(s.actions))
        assert np.array_equal(ep.rewards, np.array(s.rewards))
        assert np.array_equal(ep.terminations, np.array(s.terminations))
        assert np.allclose(ep.infos["solve_ms"][1:], s.solve_ms)
    assert obs.shape == (sum(len(s.actions) for s in streams), 79) and act.shape[1] == 8
