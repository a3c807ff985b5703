"""Imitation-learning pieces that need no expert: BC, the network, the dataset format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from features_reference import featurize_reference
from gymnasium.spaces import Box

from baselines.imitation import bc, dataset
from baselines.loaders.clone_policy import ClonedPolicy
from baselines.networks.features import (
    FEATURE_DIMS,
    FEATURES,
    FEEDFORWARD,
    CompiledInputs,
    prepare,
)
from baselines.networks.mlp import MLPPolicyNet
from uvms_env.policy import AgentSpec
from uvms_env.robot.memory import RobotMemory
from uvms_env.robot.priors import featurize

FEATURE_DIM = FEATURE_DIMS["uvms-v1"]


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


def _observations(rng: np.random.Generator, n: int, scale: float = 3.0) -> np.ndarray:
    """Arbitrary observations with the layout's structure: half without obstacles (the
    padding), the others with positive radii; unit-norm-ish grasp rotations do not
    matter to the feature code."""
    obs = rng.normal(size=(n, 79)) * scale
    obs[::2, 50:65] = np.tile([100, 100, 0, 0, 0], 3)
    obs[1::2, 53:65:5] = np.abs(obs[1::2, 53:65:5])
    return obs


@pytest.fixture(scope="module")
def paper_spec(paper):
    return AgentSpec.from_scenario(paper, 0)


def test_saved_network_reproduces_its_decisions(tmp_path, paper_spec):
    """Compiled and numpy decisions against torch's; on ``memory`` features the policy
    builds the memory block from its stream (a ``RobotMemory`` beside it here)."""
    rng = np.random.default_rng(1)
    obs = _observations(rng, 500, 1.0).astype(np.float32)
    blocks = rng.normal(0.0, 0.3, (len(obs), 16)).astype(np.float32)
    ring = paper_spec.object_key
    cases = [(f, (32, 32)) for f in FEATURES] + [("features", ())]  # (): linear feedback
    for features, hidden in cases:
        data = np.concatenate([obs, blocks], 1) if features == "memory" else obs
        net, _ = bc.fit(data, np.tanh(obs[:, :8]), epochs=2, features=features, hidden=hidden,
                        progress=False, object_key=ring)  # fmt: skip
        net.save(tmp_path / "policy.pt")
        again = MLPPolicyNet.load(tmp_path / "policy.pt")
        assert again.features == features and again.residual == (features in FEEDFORWARD)
        for compiled in (True, False):  # the whole decision compiled, or numpy layers
            policy = ClonedPolicy(paper_spec, tmp_path / "policy.pt", compiled=compiled)
            memory = RobotMemory(paper_spec.period, ring)
            for o in obs[:20]:
                x = np.concatenate([o, memory.observe(o)]) if features == "memory" else o
                a = policy.act(o)
                memory.issued(a)
                assert a.shape == (8,) and np.all(np.abs(a) <= 1)
                assert np.allclose(a, again.predict(x[None], ring)[0], atol=1e-5)  # torch


def test_compiled_features_agree_with_numpy_and_are_yaw_invariant():
    rng = np.random.default_rng(3)
    obs = _observations(rng, 200)
    batched = featurize(obs)
    unscaled = CompiledInputs("uvms-v1", np.zeros(FEATURE_DIM), np.ones(FEATURE_DIM), clip=1e30)
    single = np.stack([unscaled(o)[:FEATURE_DIM].copy() for o in obs])
    assert batched.shape == (200, FEATURE_DIM)
    assert np.allclose(batched, single, atol=1e-5)
    assert np.allclose(batched, featurize_reference(obs), atol=1e-5)  # written apart
    # rotate the whole world about the vertical by 0.7 rad and shift it: same features
    th, shift = 0.7, np.array([3.0, -2.0])
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    moved = obs.copy()
    for i in (0, 20, 32, 38):  # positions
        moved[:, i : i + 2] = obs[:, i : i + 2] @ rot.T + shift
    for i in (26, 29, 44, *range(50, 65, 5)):  # NED vectors and obstacle offsets
        moved[:, i : i + 2] = obs[:, i : i + 2] @ rot.T
    for i in (5, 25, 37, 43):  # headings
        moved[:, i] = obs[:, i] + th
    pad = obs[:, 53] <= 0
    moved[pad, 50:52] = obs[pad, 50:52]  # padding is not a place
    assert np.allclose(featurize(moved), batched, atol=1e-4)


def test_steady_input_feature_is_the_experts_own(paper):
    """The a_ss the clone computes from its observation alone equals the expert's, which
    takes the grasp, load share and object from the spec (an independent path)."""
    import uvms_env
    from uvms_env.dynamics import ObjectModel
    from uvms_env.dynamics.local_model import ModelParams, build_local_model, build_steady_input
    from uvms_env.dynamics.uvms import default_model

    for scenario, kwargs in (("paper", {}), ("random", {"n_agents": 3})):
        env = uvms_env.parallel_env(scenario=scenario, seed=4, **kwargs)
        obs, _ = env.reset(seed=4)
        for i, agent in enumerate(env.possible_agents):
            spec = AgentSpec.from_scenario(env.scenario, i)
            ring = spec.object_key
            obj = ObjectModel(spec.object_shape, spec.object_size)
            steady = build_steady_input(
                default_model(), obj, build_local_model(default_model(), obj)
            )
            theta = ModelParams(
                spec.grasp_offset, spec.grasp_rotation, spec.load_share, obj.nominal_parameters()
            ).pack()
            o = obs[agent].astype(float)
            want = np.asarray(steady(o[:20], theta, o[44:50])).ravel()
            got = prepare(obs[agent][None], "features", ring)[0, -8:]
            assert np.allclose(got, want, atol=1e-5)
            dim = FEATURE_DIMS["features"]
            compiled = CompiledInputs("features", np.zeros(dim), np.ones(dim), ring, clip=1e30)
            assert np.allclose(compiled(obs[agent])[dim + 1 :], want, atol=1e-9)
            assert np.abs(want).max() > 0.01  # a real holding input, not zeros


def test_feedforward_features_need_the_object():
    obs = _observations(np.random.default_rng(6), 4)
    with pytest.raises(ValueError, match="need the object"):
        prepare(obs, "features")
    with pytest.raises(ValueError, match="did not record it"):
        prepare(obs, "features", np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="need the object"):
        CompiledInputs("features", np.zeros(84), np.ones(84))


def test_residual_network_adds_its_output_to_the_steady_input():
    rng = np.random.default_rng(8)
    net = MLPPolicyNet(84, hidden=(16,), features="features")
    x = rng.normal(size=(50, 84)).astype(np.float32)
    import torch

    with torch.no_grad():
        for p in net.body.parameters():
            p.zero_()  # a network that outputs nothing: the action is a_ss itself
        assert np.allclose(net(torch.as_tensor(x)).numpy(), x[:, -8:])


def test_std_loss_scale_weights_components_by_inverse_variance():
    rng = np.random.default_rng(4)
    act = rng.normal(size=(5000, 3)) * np.array([0.3, 0.1, 0.0])  # last: constant
    w = bc.loss_weights(act, "std")
    assert np.isclose(w.mean(), 1.0)
    assert np.isclose(w[1] / w[0], 9.0, rtol=0.05)  # (0.3 / 0.1) ** 2
    assert np.isclose(w[2] / w[0], (0.3 / bc.MIN_ACTION_STD) ** 2, rtol=0.05)
    assert np.array_equal(bc.loss_weights(act, "none"), np.ones(3))


def test_std_loss_scale_balances_the_relative_errors_of_small_and_large_components():
    rng = np.random.default_rng(5)
    obs = rng.normal(size=(4000, 6)).astype(np.float32)
    act = np.stack([0.8 * np.tanh(obs[:, 0]), 0.05 * np.tanh(obs[:, 1])], 1).astype(np.float32)
    rel = {}
    for scale in bc.LOSS_SCALES:
        net, _ = bc.fit(obs, act, epochs=30, lr=3e-3, hidden=(32, 32), loss_scale=scale,
                        progress=False)  # fmt: skip
        rel[scale] = np.sqrt(((net.predict(obs) - act) ** 2).mean(0)) / act.std(0)
    # unweighted MSE neglects the small component; per-component 1/var weights do not
    assert rel["none"][1] > 3 * rel["none"][0]
    assert rel["std"][1] < 2 * rel["std"][0]
    assert rel["std"][1] < rel["none"][1]


def test_bc_rejects_mismatched_data():
    with pytest.raises(ValueError, match="must match"):
        bc.fit(np.zeros((10, 3)), np.zeros((9, 8)), progress=False)
    with pytest.raises(ValueError, match="lr_schedule"):
        bc.fit(np.zeros((10, 3)), np.zeros((10, 8)), lr_schedule="step", progress=False)
    with pytest.raises(ValueError, match="loss_scale"):
        bc.fit(np.zeros((10, 3)), np.zeros((10, 8)), loss_scale="max", progress=False)


def _streams() -> list[dataset.AgentStream]:
    """Three short robot streams carrying objects of keys 0, 0.5 and 1."""
    rng = np.random.default_rng(2)
    streams = []
    for k in range(3):
        s = dataset.AgentStream.start(rng.normal(size=79), seed=k, object_key=0.5 * k)
        for t in range(5 + k):
            s.actions.append(rng.uniform(-1, 1, 8).astype(np.float32))
            s.observations.append(rng.normal(size=79).astype(np.float32))
            s.rewards.append(float(t))
            s.terminations.append(t == 4 + k)
            s.truncations.append(False)
            s.solve_ms.append(1.0 + t)
        streams.append(s)
    return streams


def _write(streams: list[dataset.AgentStream], root: Path, name: str) -> None:
    space_o = Box(-np.inf, np.inf, (79,), np.float32)
    space_a = Box(-1, 1, (8,), np.float32)
    dataset.write_dataset(streams, root, name, space_o, space_a)


def test_dataset_round_trip(tmp_path):
    streams = _streams()
    _write(streams, tmp_path, "roundtrip")
    obs, act, episodes = dataset.read_dataset(tmp_path, "roundtrip")
    assert len(episodes) == 3
    for s, ep in zip(streams, episodes, strict=True):
        assert np.array_equal(ep.observations, np.stack(s.observations))
        assert np.array_equal(ep.actions, np.stack(s.actions))
        assert np.array_equal(ep.rewards, np.array(s.rewards))
        assert np.array_equal(ep.terminations, np.array(s.terminations))
        assert np.allclose(ep.infos["solve_ms"][1:], s.solve_ms)
        assert np.all(ep.infos["object_key"] == s.object_key)
    assert obs.shape == (sum(len(s.actions) for s in streams), 79) and act.shape[1] == 8
    _, _, ring, n = dataset.read_many([tmp_path / "roundtrip"])
    assert n == 3 and np.array_equal(ring, np.repeat([0.0, 0.5, 1.0], [5, 6, 7]))


def test_a_dataset_recorded_under_the_old_object_key_name_still_loads(tmp_path, monkeypatch):
    """Datasets recorded before the rename store the object's key as
    ``object_ring_radius``: they read as if recorded now."""
    streams = _streams()
    write_infos = dataset._infos

    def old_infos(s: dataset.AgentStream) -> dict[str, np.ndarray]:
        infos = write_infos(s)
        infos["object_ring_radius"] = infos.pop("object_key")
        return infos

    with monkeypatch.context() as m:
        m.setattr(dataset, "_infos", old_infos)
        _write(streams, tmp_path, "old")
    _write(streams, tmp_path, "new")
    _, _, episodes = dataset.read_dataset(tmp_path, "old")
    assert all("object_key" not in ep.infos and "object_ring_radius" in ep.infos for ep in episodes)
    assert [dataset.object_key_of(ep) for ep in episodes] == [0.0, 0.5, 1.0]
    _, _, ring, n = dataset.read_many([tmp_path / "old", tmp_path / "new"])
    keys = np.repeat([0.0, 0.5, 1.0], [5, 6, 7])
    assert n == 6 and np.array_equal(ring, np.concatenate([keys, keys]))


def test_a_clone_saved_under_the_earlier_feature_name_reads_as_features():
    """A clone saved when the feature set was called ``uvms-v2`` (the committed clone of
    0f56e9d) loads as ``features``, the environment's observation mode's name."""
    import torch

    path = Path(__file__).parents[1] / "golden" / "features_clone_0f56e9d.pt"
    saved = torch.load(path, map_location="cpu", weights_only=False)["features"]
    net = MLPPolicyNet.load(path)
    assert saved == "uvms-v2" and net.features == "features"
    assert net.residual  # the steady input is fed forward


def test_margin_weights_grow_towards_a_limit():
    from baselines.imitation.bc import margin_weights
    from uvms_env.robot.observation import OBSERVATION_STRUCTURE as ST

    obs = np.zeros((4, 79), np.float32)
    rate = ST["zeta"].start + 7  # a joint rate
    obs[1, rate] = 0.05  # half the 0.1 rad/s limit: the inner half, no extra weight
    obs[2, rate] = -0.075  # three quarters: p = 0.5
    obs[3, ST["q"].start + 8] = 2.5  # a joint beyond its 2 rad limit: p = 1
    w = margin_weights(obs, 4.0)
    np.testing.assert_allclose(w / w[0], [1.0, 1.0, 2.0, 5.0], rtol=1e-6)
    assert w.mean() == pytest.approx(1.0)
    assert np.array_equal(margin_weights(obs, 0.0), np.ones(4))
    with pytest.raises(ValueError, match=">= 0"):
        margin_weights(obs, -1.0)
