"""The cloned MLP's whole decision as one compiled function (``baselines.networks.mlp_decision``)
against the torch network it was built from."""

from __future__ import annotations

import itertools
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

import uvms_env
from baselines.loaders.clone_policy import ClonedPolicy
from baselines.networks.mlp import MLPPolicyNet
from baselines.networks.mlp_decision import (
    TANH_LIMIT,
    TANH_P,
    TANH_Q,
    dense_c,
    layer_widths,
    mlp_decision_function,
    pack_layers,
)
from uvms_env.dynamics.compiled import compile_function
from uvms_env.policy import AgentSpec

pytest.importorskip("torch")

# A clone on the ``features`` inputs (the committed dagger:pretrained of 0f56e9d, trained
# on random N = 2; today's committed clone reads ``memory``, tested with its memory block
# in test_distribution_training): realistic weights for the compiled layers.
MLP = Path(__file__).parents[1] / "golden" / "features_clone_0f56e9d.pt"
# Compiled C, numpy and torch evaluate the same float32 layers in different summation
# orders, and torch's matmul follows the machine's BLAS kernel: measured at most 5.4e-7
# (compiled) and 6.0e-7 (numpy) from torch on this file's rollout with OPENBLAS_CORETYPE
# unset, Haswell and Sandybridge; the bound leaves a 15x margin for other kernels. Every
# comparison with the committed clone goes through this tolerance, never bit for bit.
TOL = 1e-5  # absolute, on normalized inputs in [-1, 1]


def _compiled(policy: ClonedPolicy) -> ClonedPolicy:
    if not policy.compiled:
        pytest.skip("no C compiler (or UVMS_ENV_NO_COMPILE): the clone keeps numpy layers")
    return policy


@pytest.fixture(scope="module")
def rollout():
    """Observations of both robots of a random N = 2 episode driven by the compiled MLP,
    with the robots' specs and the policies that drove it."""
    env = uvms_env.parallel_env(scenario="random", seed=23, n_agents=2)
    obs, _ = env.reset(seed=23)
    specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(len(env.agents))]
    policies = [_compiled(ClonedPolicy(s, MLP)) for s in specs]
    seen: list[list[np.ndarray]] = [[] for _ in specs]
    for _ in range(150):
        if not env.agents:
            break
        actions = {}
        for i, agent in enumerate(env.possible_agents):
            if agent in env.agents:
                seen[i].append(obs[agent].copy())
                actions[agent] = policies[i].act(obs[agent])
        obs, *_ = env.step(actions)
    return [np.stack(s) for s in seen], specs, policies


def test_compiled_mlp_acts_as_the_torch_network_on_a_rollout(rollout):
    seen, specs, policies = rollout
    for obs, spec, policy in zip(seen, specs, policies, strict=True):
        assert len(obs) >= 100
        want = policy.net.predict(obs, spec.object_key)
        got = np.stack([policy.act(o) for o in obs])
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=0, atol=TOL)
        numpy_layers = ClonedPolicy(spec, MLP, compiled=False)
        assert not numpy_layers.compiled
        numpy_got = np.stack([numpy_layers.act(o) for o in obs])
        np.testing.assert_allclose(numpy_got, want, rtol=0, atol=TOL)


def test_compiled_mlp_clips_as_the_torch_network(rollout):
    """Far outside the data: inputs past +-10 std, hidden units past the tanh
    approximation's range and actions past the saturation, all clipped as in torch."""
    seen, specs, policies = rollout
    rng = np.random.default_rng(5)
    obs = np.repeat(seen[0][::10], 4, axis=0)
    obs[:, 10:20] += rng.normal(size=(len(obs), 10)) * 5.0  # body twist, joint rates
    obs[:, 32:38] += rng.normal(size=(len(obs), 6)) * 20.0  # far waypoints
    spec, policy = specs[0], policies[0]
    net = policy.net
    from baselines.networks.features import INPUT_CLIP, prepare

    x = prepare(obs, net.features, spec.object_key)
    z = (x - net.obs_mean.numpy()) / net.obs_std.numpy()
    assert (np.abs(z) > INPUT_CLIP).any()
    w, b = net.numpy_weights()[0]
    assert (np.abs(np.clip(z, -INPUT_CLIP, INPUT_CLIP) @ w + b) > TANH_LIMIT).any()
    want = net.predict(obs, spec.object_key)
    got = np.stack([policy.act(o) for o in obs])
    assert (np.abs(want) == 1.0).mean() > 0.1
    assert np.all(np.abs(got) <= 1.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


def tanh_approx(x: np.ndarray) -> np.ndarray:
    """The generated code's tanh, in numpy float32 with the same operations."""
    t = np.clip(np.asarray(x, dtype=np.float32), -TANH_LIMIT, TANH_LIMIT)
    s = t * t
    p, q = np.float32(0.0), np.float32(0.0)
    for c in TANH_P[::-1]:
        p = p * s + np.float32(c)
    for c in TANH_Q[::-1]:
        q = q * s + np.float32(c)
    return t * p / q


def test_tanh_approximation():
    x = np.linspace(-12.0, 12.0, 200_001, dtype=np.float32)
    assert np.abs(tanh_approx(x).astype(float) - np.tanh(x.astype(float))).max() < 4e-7
    assert np.array_equal(tanh_approx(-x), -tanh_approx(x))


@pytest.mark.parametrize("widths", [(79, 30, 20, 8), (84, 5, 8), (7, 64, 3)])
def test_generated_layers_compute_the_network(widths):
    """Any widths: blocks that do not divide 32, inputs padded for the partial sums."""
    rng = np.random.default_rng(sum(widths))
    layers = [
        np.vstack([rng.normal(size=(n, m)) / np.sqrt(n), rng.normal(size=(1, m)) * 0.1])
        for n, m in itertools.pairwise(widths)
    ]
    layers = [w.astype(np.float32) for w in layers]
    assert layer_widths(layers) == widths
    packed = pack_layers(layers)
    z, weights = cs.MX.sym("z", widths[0]), cs.MX.sym("weights", len(packed))
    node = cs.Function.jit(
        "layers_under_test",
        dense_c(widths),
        ["z", "weights"],
        ["y"],
        [cs.Sparsity.dense(widths[0]), weights.sparsity()],
        [cs.Sparsity.dense(widths[-1])],
        {"jit": False},
    )
    name = f"dense_test_{'_'.join(map(str, widths))}"
    outer = cs.Function(name, [z, weights], [node(z, weights)])
    fn = compile_function(outer)
    if fn is outer:
        pytest.skip("no C compiler (or UVMS_ENV_NO_COMPILE)")
    x = rng.normal(size=(50, widths[0])) * 3

    def network(layers: list[np.ndarray]) -> np.ndarray:
        h = x
        for w in layers[:-1]:
            h = np.tanh(h @ w[:-1] + w[-1])
        return h @ layers[-1][:-1] + layers[-1][-1]

    want = network(layers)
    got = np.stack([np.asarray(fn(v, packed)).ravel() for v in x])
    assert np.abs(got - want).max() < TOL * max(1.0, np.abs(want).max())
    # the weights are an input: other weights of the same widths, the same library
    other = [w[::-1].copy() for w in layers]
    moved = np.stack([np.asarray(fn(v, pack_layers(other))).ravel() for v in x])
    want = network(other)
    assert np.abs(moved - want).max() < TOL * max(1.0, np.abs(want).max())
    assert np.abs(moved - got).max() > 1e-3


def test_without_a_compiler_the_policy_keeps_numpy_layers(monkeypatch, tmp_path, paper):
    import torch

    monkeypatch.setenv("UVMS_ENV_NO_COMPILE", "1")
    net = MLPPolicyNet.load(MLP)
    with torch.no_grad():
        net.body[0].bias.add_(0.01)  # weights no earlier test has compiled in this process
    net.save(tmp_path / "policy.pt")
    layers = [np.vstack([w, b[None]]) for w, b in net.numpy_weights()]
    assert mlp_decision_function("features", 0.0, layer_widths(layers), True, 79) is None
    spec = AgentSpec.from_scenario(paper, 0)
    policy = ClonedPolicy(spec, tmp_path / "policy.pt")
    assert not policy.compiled
    env = uvms_env.parallel_env(scenario="paper", seed=0)
    obs, _ = env.reset(seed=0)
    o = obs[env.agents[0]]
    want = net.predict(o[None], spec.object_key)[0]
    np.testing.assert_allclose(policy.act(o), want, rtol=0, atol=TOL)
