"""``observation_mode="memory"`` (``uvms_env.robot.memory``): the layout, the memory block
against an independent recomputation from the robot's own stream, the policy-side
``RobotMemory`` against the environment's, locality, and the batched env against the
single one."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

import uvms_env
from uvms_env.dynamics import NQ, NU
from uvms_env.dynamics.local_model import local_terms, theta_size
from uvms_env.dynamics.uvms import default_model
from uvms_env.robot.memory import DISTURBANCE_GAIN, DISTURBANCE_LIMIT, RobotMemory
from uvms_env.robot.observation import OBSERVATION_STRUCTURE as ST
from uvms_env.robot.priors import BASE_FEATURES, MEMORY_FEATURES_SIZE, object_model
from uvms_env.vector import VectorEnv

STEPS = 12
KW = {"current": "mild", "mismatch": 0.1, "max_cycles": 40}


def _actions(n: int) -> np.ndarray:
    # past the saturation now and then: the memory keeps the clipped command
    return np.random.default_rng(2).uniform(-1.3, 1.3, (STEPS, n, NU))


def _stream(mode: str, scenario: str = "random", **kw):
    """Observations of one episode in torque mode under ``_actions``."""
    env = uvms_env.parallel_env(scenario, n_agents=3, observation_mode=mode, **KW, **kw)
    obs, _ = env.reset(seed=9)
    agents = env.possible_agents
    out = [np.stack([obs[a] for a in agents])]
    for act in _actions(env.n):
        obs, *_ = env.step({a: act[i] for i, a in enumerate(agents)})
        out.append(np.stack([obs[a] for a in agents]))
    return env, np.stack(out)


@pytest.fixture(scope="module")
def streams():
    _, raw = _stream("raw")
    _, feats = _stream("features")
    env, mem = _stream("memory")
    return env, raw, feats, mem


def _reference_blocks(raw: np.ndarray, ring: float, period: float) -> np.ndarray:
    """The memory blocks recomputed from one robot's raw stream and its own commands, in
    numpy around the local model's mass matrix and forces: w = M dzeta/h - B tau_max u - r,
    d <- clip(d + g (B^T w / tau_max - d))."""
    uvms = default_model()
    obj = object_model(ring)
    q, zeta = cs.SX.sym("q", NQ), cs.SX.sym("z", NQ)
    theta = cs.SX.sym("t", theta_size(obj))
    terms = cs.Function("terms", [q, zeta, theta], list(local_terms(uvms, obj, q, zeta, theta)))
    b, tau_max = np.asarray(uvms.B), np.asarray(uvms.params.limits.tau_max, float)
    commands = np.clip(_actions(raw.shape[1]), -1, 1).astype(np.float32).astype(np.float64)
    out = np.zeros((len(raw), raw.shape[1], 2 * NU))
    for i in range(raw.shape[1]):
        d = np.zeros(NU)
        for t in range(1, len(raw)):
            o, nxt = raw[t - 1, i].astype(float), raw[t, i].astype(float)
            r_oi = o[ST["grasp_rotation"]].reshape(3, 3)  # row-major R_Oi
            th = np.concatenate([o[ST["grasp_offset"]], r_oi.T.reshape(-1), o[ST["load_share"]],
                                 object_model(ring).nominal_parameters()])  # fmt: skip
            m, r = (np.asarray(x).ravel() for x in terms(o[ST["q"]], o[ST["zeta"]], th))
            m = m.reshape(NQ, NQ)
            u = commands[t - 1, i]
            w = m @ (nxt[ST["zeta"]] - o[ST["zeta"]]) / period - b @ (tau_max * u) - r
            d = np.clip(d + DISTURBANCE_GAIN * (b.T @ w / tau_max - d), -DISTURBANCE_LIMIT,
                        DISTURBANCE_LIMIT)  # fmt: skip
            out[t, i] = np.concatenate([u, d])
    return out


def test_memory_observation_is_features_with_the_memory_between(streams):
    env, _, feats, mem = streams
    assert mem.shape[-1] == MEMORY_FEATURES_SIZE == env.observation_space("uvms_0").shape[0]
    np.testing.assert_array_equal(mem[..., :BASE_FEATURES], feats[..., :BASE_FEATURES])
    np.testing.assert_array_equal(mem[..., -NU:], feats[..., -NU:])
    assert not mem[0, :, BASE_FEATURES:-NU].any()  # nothing sent, nothing estimated yet


def test_memory_block_matches_an_independent_recomputation(streams):
    env, raw, _, mem = streams
    ring, period = env.scenario.object_key, env.scenario.period
    ref = _reference_blocks(raw, ring, period)
    block = mem[..., BASE_FEATURES:-NU]
    np.testing.assert_allclose(block[..., :NU], ref[..., :NU], rtol=0, atol=1e-7)
    np.testing.assert_allclose(block[..., NU:], ref[..., NU:], rtol=1e-4, atol=1e-4)
    assert np.abs(ref[-1, :, NU:]).max() > 1e-2  # a current and mismatch: something to see


def test_robot_memory_from_its_own_stream_is_the_environments(streams):
    """A policy's ``RobotMemory`` fed only that robot's raw observations and its own
    commands rebuilds the environment's memory block exactly: the block is local."""
    env, raw, _, mem = streams
    spec_ring, period = env.scenario.object_key, env.scenario.period
    commands = _actions(raw.shape[1])
    for i in range(raw.shape[1]):
        memory = RobotMemory(period, spec_ring)
        for t in range(len(raw)):
            block = memory.observe(raw[t, i])
            np.testing.assert_array_equal(block, mem[t, i, BASE_FEATURES:-NU])
            if t < len(commands):
                memory.issued(np.clip(commands[t, i], -1, 1).astype(np.float32))
        memory.reset()
        assert not memory.observe(raw[0, i]).any()


def test_vector_env_memory_matches_the_single_env(streams):
    _, _, _, mem = streams
    venv = VectorEnv("random", num_envs=2, n_agents=3, observation_mode="memory", **KW)
    obs, _ = venv.reset(seed=[9, 10])
    out = [obs[0]]
    for act in _actions(3):
        obs, *_ = venv.step(np.stack([act, act]))
        out.append(obs[0])
    np.testing.assert_allclose(np.stack(out), mem, rtol=0, atol=1e-5)


def test_executed_replaces_the_issued_command():
    env = uvms_env.parallel_env("paper", observation_mode="raw")
    obs, _ = env.reset(seed=0)
    ring, period = env.scenario.object_key, env.scenario.period
    a, b = RobotMemory(period, ring), RobotMemory(period, ring)
    for m in (a, b):
        m.observe(obs["uvms_0"])
    a.issued(np.full(NU, 0.5, np.float32))
    a.executed(np.full(NU, -0.2, np.float32))
    b.issued(np.full(NU, -0.2, np.float32))
    nxt, *_ = env.step({x: np.full(NU, -0.2, np.float32) for x in env.agents})
    np.testing.assert_array_equal(a.observe(nxt["uvms_0"]), b.observe(nxt["uvms_0"]))
