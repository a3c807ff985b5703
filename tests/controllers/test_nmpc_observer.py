"""NMPC expert's offset-free prediction: the disturbance observer converges to a known
injected generalized force's effect, the paper controller switch reproduces the decisions
of the controller before the observer existed, and each controller reads only its own
observation.

Fast: the paper scenario's OCP library (compiled once per machine, then loaded).
"""

from __future__ import annotations

from pathlib import Path

import casadi as cs
import numpy as np
import pytest
from script_loader import load_script

import uvms_env
from nmpc_expert import NMPCPolicy, NMPCSettings, make_policy
from nmpc_expert.observation_reader import OBSERVATION_STRUCTURE
from uvms_env.dynamics import NQ, NU, ObjectModel
from uvms_env.dynamics.local_model import NX, local_terms, theta_size
from uvms_env.dynamics.uvms import default_model
from uvms_env.policy import AgentSpec

# Observations and actions of both robots over the first 80 periods of the paper scenario
# (seed 0), recorded with the expert as it was before the disturbance observer (commit
# 9b54d41: ``NMPCPolicy(spec)`` then, the paper's controller).
GOLDEN = Path(__file__).parents[1] / "golden" / "paper_controller_9b54d41.npz"


@pytest.fixture(scope="module")
def env():
    return uvms_env.parallel_env(scenario="paper")


def _plant(spec: AgentSpec, settings: NMPCSettings, force: np.ndarray):
    """One period of the robot's local model with a constant generalized force ``force``
    added to its dynamics, M zeta_dot = B tau + r + force (RK4, 8 substeps): the
    'truth' the observer must learn, built here from the model's terms, not from the
    controller's compiled prediction."""
    uvms = default_model()
    obj = ObjectModel(spec.object_shape, spec.object_key)
    x, a, th = cs.SX.sym("x", NX), cs.SX.sym("a", NU), cs.SX.sym("th", theta_size(obj))
    f = cs.SX.sym("f", NQ)
    q, zeta = x[:NQ], x[NQ:]
    m_loc, r = local_terms(uvms, obj, q, zeta, th)
    tau = cs.DM(np.asarray(uvms.params.limits.tau_max, float)) * a
    zdot = cs.solve(0.5 * (m_loc + m_loc.T), cs.DM(uvms.B) @ tau + r + f)
    rhs = cs.Function("rhs", [x, a, th, f], [cs.vertcat(uvms.qdot_map(q) @ zeta, zdot)])
    dt = settings.period / 8
    xk = x
    for _ in range(8):
        k1 = rhs(xk, a, th, f)
        k2 = rhs(xk + dt / 2 * k1, a, th, f)
        k3 = rhs(xk + dt / 2 * k2, a, th, f)
        k4 = rhs(xk + dt * k3, a, th, f)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = cs.Function("step", [x, a, th, f], [xk])
    return lambda x0, act, theta, with_force: np.asarray(
        step(x0, act, theta, force if with_force else np.zeros(NQ))
    ).ravel()


def test_observer_converges_to_an_injected_generalized_force(env):
    """Plant: the robot's local model plus a known constant generalized force on the
    vehicle's surge and every joint. The observer's estimate d must converge to what
    that force adds to the velocities in one period (plant with minus plant without the
    force, from the same state and input), the innovation must vanish, the speed margins
    must follow the innovation's spread, and the estimate must be in the solver's
    prediction. Reset clears it all."""
    obs, _ = env.reset(seed=0)
    spec = AgentSpec.from_scenario(env.scenario, 0)
    pol = NMPCPolicy(spec)
    s = pol.settings
    assert s.disturbance_observer
    force = np.zeros(NQ)
    force[0] = 3.0  # N along surge
    force[6:] = [0.02, -0.03, 0.03, -0.01]  # N m on the joints
    plant = _plant(spec, s, force)
    st = OBSERVATION_STRUCTURE
    o = np.asarray(obs[env.possible_agents[0]], dtype=np.float64).copy()
    x = np.concatenate([o[st["q"]], o[st["zeta"]]])
    for _ in range(40):
        o[st["q"]], o[st["zeta"]] = x[:NQ], x[NQ:]
        a = pol.act(o)
        effect = (plant(x, a, pol.theta, True) - plant(x, a, pol.theta, False))[NQ:]
        x = plant(x, a, pol.theta, True)
    o[st["q"]], o[st["zeta"]] = x[:NQ], x[NQ:]
    predicted = pol.solver.xbar[1, NQ:].copy()  # the plan's one-step prediction
    pol.act(o)  # measures the last period's innovation
    scale = pol._bounds[2][:NQ]
    np.testing.assert_array_equal(pol.innovation, x[NQ:] - predicted)
    joint = np.max(np.abs(pol.innovation[6:] / scale[6:]))
    assert pol.stats["innovation_joint_max"] == pytest.approx(joint, rel=1e-12)
    assert np.max(np.abs(effect / scale)) > 0.05  # the force matters (in speed limits)
    # to 1% of the largest effect: the estimate also absorbs what the controller's own
    # prediction (2 RK4 substeps, linearized about the plan) misses of the plant's 8
    np.testing.assert_allclose(pol.disturbance, effect, rtol=0, atol=1e-2 * np.max(np.abs(effect)))
    np.testing.assert_array_equal(pol.solver.disturbance[NQ:], pol.disturbance)
    assert not pol.solver.disturbance[:NQ].any()
    # adaptive margins: the bounds of the speed rows move inwards by k sigma, capped
    margin = np.minimum(s.margin_gain * np.sqrt(pol.innovation_var) / scale, s.margin_limit)
    lower, upper, _ = pol._bounds
    np.testing.assert_allclose(pol._upper[:NQ], upper[:NQ] - margin)
    np.testing.assert_allclose(pol._lower[:NQ], lower[:NQ] + margin)
    np.testing.assert_array_equal(pol._upper[NQ:], upper[NQ:])
    assert margin.max() > 0 and not pol.rate_offset.any()  # the bound shift is off
    # the input reference's shift: on the surge thruster, the input that cancels
    # observer_input_gain of the surge estimate in one period of the plant (a finite
    # difference through the plant, not the controller's linearization); no shift on
    # the inputs of the angular rates and joints
    k = int(np.argmax(np.asarray(default_model().B)[0]))
    shift = pol.solver.input_offset.copy()
    assert 0 < abs(shift[k]) < s.observer_input_limit
    bumped = a.copy()
    bumped[k] += shift[k]
    cancel = (plant(x, bumped, pol.theta, True) - plant(x, a, pol.theta, True))[NQ]
    np.testing.assert_allclose(cancel, -s.observer_input_gain * pol.disturbance[0], rtol=0.05)
    linear = np.asarray(default_model().B)[:3].argmax(axis=1)
    assert not np.delete(shift, linear).any()
    pol.reset()  # back to the cold start: no estimate, the initial margin
    assert not pol.disturbance.any() and not pol.solver.input_offset.any()
    assert not pol.innovation.any()
    np.testing.assert_allclose(pol._upper[:NQ], upper[:NQ] - s.margin_initial)
    np.testing.assert_allclose(pol._lower[:NQ], lower[:NQ] + s.margin_initial)
    np.testing.assert_array_equal(pol._upper[NQ:], upper[NQ:])


def test_start_margin_floors_the_adaptive_margin_then_falls_to_zero(env):
    """``start_margin``: at decision k the speed rows' margin is max(min(k sigma,
    margin_limit), start_margin (1 - k h / start_margin_s) times the row's bound): the
    floor binds at the start (above margin_initial), is gone after ``start_margin_s``, and
    comes back at reset; the settings refuse a floor without its duration or without the
    observer."""
    obs, _ = env.reset(seed=0)
    spec = AgentSpec.from_scenario(env.scenario, 0)
    pol = make_policy("rti", start_margin=0.6, start_margin_s=0.6)(spec)
    s = pol.settings
    lower, upper, scale = pol._bounds
    o = obs[env.possible_agents[0]]
    np.testing.assert_allclose(pol._upper[:NQ], 0.4 * upper[:NQ])
    for k in range(8):  # decision k, at k periods into the episode
        pol.act(o)
        floor = 0.6 * max(0.0, 1 - k * s.period / 0.6)
        assert s.start_floor(k * s.period) == pytest.approx(floor)
        adaptive = np.minimum(
            s.margin_gain * np.sqrt(pol.innovation_var) / scale[:NQ], s.margin_limit
        )
        margin = np.maximum(adaptive, floor * upper[:NQ])
        np.testing.assert_allclose(pol._upper[:NQ], upper[:NQ] - margin)
        np.testing.assert_allclose(pol._lower[:NQ], lower[:NQ] + margin)
        assert not pol.stats["status"].startswith("fallback")
    assert floor == 0  # the eighth decision, 0.84 s in: past the 0.6 s
    pol.reset()
    np.testing.assert_allclose(pol._upper[:NQ], 0.4 * upper[:NQ])
    for bad in (
        {"start_margin": 0.5},
        {"start_margin_s": 2.0},
        {"start_margin": 1.0, "start_margin_s": 2.0},
    ):
        with pytest.raises(ValueError, match="start_margin"):
            NMPCSettings(**bad)
    with pytest.raises(ValueError, match="disturbance_observer"):
        NMPCSettings.paper(start_margin=0.5, start_margin_s=2.0)


def test_paper_controller_reproduces_the_decisions_before_the_observer():
    """``NMPCSettings.paper()`` (and ``make_policy(controller="paper")``), fed each robot's
    recorded observations, reproduce the recorded actions of the controller before the
    observer existed."""
    rec = np.load(GOLDEN)
    obs, actions = rec["observations"], rec["actions"]
    env = uvms_env.parallel_env(scenario="paper")
    for i in range(obs.shape[1]):
        spec = AgentSpec.from_scenario(env.scenario, i)
        for pol in (
            NMPCPolicy(spec, settings=NMPCSettings.paper()),
            make_policy(controller="paper")(spec),
        ):
            replay = np.array([pol.act(o) for o in obs[:, i]])
            np.testing.assert_allclose(replay, actions[:, i], rtol=0, atol=1e-9)


@pytest.mark.parametrize("controller", ["observer", "paper"])
def test_each_controller_reads_only_its_own_observation(env, controller):
    """Closed loop of both robots; then each robot's controller, rebuilt alone and fed
    only its own recorded observations, reproduces its actions: no message, no shared
    state passes between the controllers (the observer's estimate included)."""
    obs, _ = env.reset(seed=0)
    agents = env.possible_agents
    pols = {
        a: make_policy(controller=controller)(AgentSpec.from_scenario(env.scenario, i))
        for i, a in enumerate(agents)
    }
    stream = {a: [] for a in agents}
    acted = {a: [] for a in agents}
    for _ in range(40):
        act = {}
        for a in agents:
            stream[a].append(obs[a].copy())
            act[a] = pols[a].act(obs[a])
            acted[a].append(act[a].copy())
        obs, *_ = env.step(act)
    for i, a in enumerate(agents):
        alone = make_policy(controller=controller)(AgentSpec.from_scenario(env.scenario, i))
        replay = np.array([alone.act(o) for o in stream[a]])
        np.testing.assert_allclose(replay, np.array(acted[a]), rtol=0, atol=1e-9)
        assert alone.settings.disturbance_observer == (controller == "observer")
        step = alone.settings.input_step
        if step is not None:  # the observer controller's bound on the input's change
            assert np.max(np.abs(np.diff(acted[a], axis=0))) <= step + 1e-9


def test_observer_needs_rti_and_validates(env):
    spec = AgentSpec.from_scenario(env.scenario, 0)
    with pytest.raises(ValueError, match="rti"):
        NMPCPolicy(spec, solver="ipopt", settings=NMPCSettings())
    with pytest.raises(ValueError, match="observer_gain"):
        NMPCSettings(observer_gain=0.0)
    with pytest.raises(ValueError, match="controller"):
        make_policy(controller="nonsense")


def test_innovation_probe_reads_each_robots_own_misses():
    """``scripts/innovation_probe.py``: per lever arm, one joint-innovation reading per
    robot and period after the first decision, each the robot's own stat, and replayed
    alike (the probe is deterministic for a seed)."""
    probe = load_script("innovation_probe")
    overrides = {"n_agents": 2, "object": "bar", "current": "mild", "max_cycles": 6}
    found = probe.innovations("nmpc", 7, overrides)
    env = uvms_env.parallel_env(scenario="random", seed=7, n_agents=2, object="bar")
    levers = sorted({round(float(np.linalg.norm(g)), 1) for g in env.scenario.grasp_offsets})
    assert sorted(found) == levers
    readings = [v for values in found.values() for v in values]
    assert len(readings) == 2 * 5 and all(v >= 0 for v in readings) and max(readings) > 0
    assert probe.innovations("nmpc", 7, overrides) == found
