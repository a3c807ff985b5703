"""NMPC expert: closed loop, locality, solver agreement, fallback, observation checks.

Fast by default (the OCP library is compiled once per machine, ~50 s, then loaded);
the full paper run is marked slow. Observations come from the environment
(``uvms_env.parallel_env``), read through its ``observation_structure``.
"""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from nmpc_expert import NMPCPolicy, NMPCSettings, make_policy
from nmpc_expert.local_controller import controller_weights, local_parameters
from nmpc_expert.observation_reader import OBSERVATION_SIZE, OBSERVATION_STRUCTURE
from nmpc_expert.ocp import CONSTRAINT_NAMES, CONSTRAINT_STATE, NC, WEIGHT_LAYOUT, build_outputs
from nmpc_expert.reference import AttitudeSlew
from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.local_model import GRASP_THETA, NX, build_local_model
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.infos import constraint_values
from uvms_env.policy import AgentSpec, Policy


@pytest.fixture(scope="module")
def env():
    return uvms_env.parallel_env(scenario="paper")


def _policies(env, **kw):
    return {
        a: NMPCPolicy(AgentSpec.from_scenario(env.scenario, i), **kw)
        for i, a in enumerate(env.possible_agents)
    }


@pytest.fixture(scope="module")
def short_run(env):
    pols = _policies(env)
    obs, _ = env.reset(seed=0)
    start = env.sim.state.x_O.copy()
    violations = []
    stream, actions = {a: [] for a in pols}, {a: [] for a in pols}
    for _ in range(60):
        act = {}
        for a, p in pols.items():
            stream[a].append(obs[a].copy())
            act[a] = p.act(obs[a])
            actions[a].append(act[a].copy())
        obs, _, term, _trunc, infos = env.step(act)
        violations.append({k: v for a in pols for k, v in constraint_values(infos[a]).items()})
        assert not any(term.values())
    return pols, start, env.sim.state.x_O.copy(), violations, stream, actions


def test_piece_fraction_sets_what_the_local_model_carries(env):
    """``piece_fraction`` above 0: the robot's model carries, with load share 1, what
    ``ObjectModel.carried_parameters`` gives; 0 (the default) its load share of the whole
    object, the paper's model."""
    spec = AgentSpec.from_scenario(env.scenario, 1)
    obj = ObjectModel(spec.object_shape, spec.object_size)
    share_at = GRASP_THETA - 1
    piece = make_policy("rti", piece_fraction=0.5)(spec)
    assert piece.theta[share_at] == 1.0
    np.testing.assert_array_equal(
        piece.theta[GRASP_THETA:],
        obj.carried_parameters(spec.grasp_offset, spec.load_share, 0.5),
    )
    np.testing.assert_array_equal(piece.theta[:share_at], local_parameters(spec)[:share_at])
    default = make_policy("rti")(spec)
    assert default.theta[share_at] == spec.load_share
    np.testing.assert_array_equal(default.theta[GRASP_THETA:], obj.nominal_parameters())
    with pytest.raises(ValueError, match="piece_fraction"):
        NMPCSettings(piece_fraction=1.5)


def test_piece_lever_ramp_sets_each_robots_fraction(env):
    """With a lever ramp each robot's fraction follows its own |l_i|: 0 at or below
    ``piece_lever_start`` (the paper's model, to the bit), ``piece_fraction`` from
    ``piece_lever_full`` on, linear between; bad ramps are refused by name."""
    s = NMPCSettings(piece_fraction=0.8, piece_lever_start=1.0, piece_lever_full=3.0)
    assert [s.piece_fraction_for(x) for x in (0.0, 1.0, 2.0, 2.5, 3.0, 9.0)] == pytest.approx(
        [0.0, 0.0, 0.4, 0.6, 0.8, 0.8]
    )
    assert NMPCSettings(piece_fraction=0.3).piece_fraction_for(7.0) == 0.3  # no ramp
    spec = AgentSpec.from_scenario(env.scenario, 0)
    lever = float(np.linalg.norm(spec.grasp_offset))
    below = make_policy("rti", piece_fraction=1.0, piece_lever_start=lever, piece_lever_full=5)
    np.testing.assert_array_equal(below(spec).theta, local_parameters(spec))
    half = make_policy(
        "rti", piece_fraction=1.0, piece_lever_start=0.0, piece_lever_full=2 * lever
    )(spec)
    np.testing.assert_allclose(half.theta, local_parameters(spec, 0.5), rtol=1e-15, atol=0)
    for bad in ({"piece_lever_start": 2.0, "piece_lever_full": 1.0}, {"piece_lever_start": 1.0}):
        with pytest.raises(ValueError, match="piece_lever"):
            NMPCSettings(**bad)


def test_policy_protocol(env):
    pol = make_policy("rti")(AgentSpec.from_scenario(env.scenario, 0))
    assert isinstance(pol, Policy)
    with pytest.raises(ValueError, match="unknown NMPC setting"):
        make_policy("rti", nonsense=1)


def test_short_closed_loop_moves_toward_waypoint_1(env, short_run):
    pols, start, end, violations, *_ = short_run
    wp1 = env.scenario.waypoints[0, :3]
    assert np.linalg.norm(end[:3] - wp1) < np.linalg.norm(start[:3] - wp1) - 1.0
    worst = {k: max(v[k] for v in violations) for k in violations[0]}
    assert all(val <= 0 for val in worst.values()), worst
    assert all(p.fallbacks == 0 for p in pols.values())
    assert all(p.stats["solve_time_ms"] < 100 for p in pols.values())


def test_rate_offset_shifts_speed_bounds(env, short_run):
    """The paper controller's offset estimator learned a nonzero one-step rate error (the
    local model misses the internal wrench) and shifted exactly the speed bounds by it,
    nothing else; reset restores the bounds."""
    *_, stream, _ = short_run
    for i, agent in enumerate(env.possible_agents):
        p = NMPCPolicy(AgentSpec.from_scenario(env.scenario, i), settings=NMPCSettings.paper())
        for o in stream[agent][:20]:
            p.act(o)
        lower, upper, scale = p._bounds
        assert 1e-4 < p.stats["rate_offset_max"] <= p.settings.offset_limit
        lim = p.settings.offset_limit
        shift = np.clip(p.rate_offset / scale[:10], -lim, lim)
        np.testing.assert_allclose(p._upper[:10], upper[:10] - shift)
        np.testing.assert_allclose(p._lower[:10], lower[:10] - shift)
        np.testing.assert_array_equal(p._upper[10:], upper[10:])
        p.reset()
        np.testing.assert_array_equal(p._upper, upper)
        assert not p.rate_offset.any()


def test_replay_reproduces_actions_no_shared_state(env, short_run):
    """Robot 1's controller, rebuilt alone and fed robot 1's recorded observations only,
    reproduces its actions: nothing hidden passes between the two controllers."""
    *_, stream, actions = short_run
    agent = env.possible_agents[1]
    alone = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 1))
    replay = np.array([alone.act(o) for o in stream[agent]])
    np.testing.assert_allclose(replay, np.array(actions[agent]), atol=1e-9)


@pytest.mark.slow  # ~35 s, most of it building IPOPT's problem; CI's budget
def test_rti_agrees_with_ipopt_on_recorded_problems(env, short_run):
    """Same warm start, same problem: the first input of one RTI step and of IPOPT's
    converged solution. Tolerance 0.01 of the saturation: the RTI is one Gauss-Newton
    step with the approximate Jacobian (``ocp``), measured ~2e-3 in steady transport;
    a 1% input difference is far below what the closed loop notices. IPOPT runs the
    paper's controller only, so the RTI runs it too (the same problem)."""
    *_, stream, _ = short_run
    spec = AgentSpec.from_scenario(env.scenario, 0)
    rti = NMPCPolicy(spec, settings=NMPCSettings.paper())
    ref = NMPCPolicy(spec, solver="ipopt")
    assert ref.settings == rti.settings
    agent = env.possible_agents[0]
    checked = 0
    for k, o in enumerate(stream[agent][:31]):
        if k in (20, 30):
            ref.solver.xbar[:] = rti.solver.xbar
            ref.solver.abar[:] = rti.solver.abar
            ref.solver.has_plan = True
            # same rate-offset state, hence the same shifted speed bounds
            ref.rate_offset[:] = rti.rate_offset
            ref._predicted_zeta = rti._predicted_zeta.copy()
            a_ref = ref.act(o)
            assert ref.fallbacks == 0, ref.stats["status"]
            a_rti = rti.act(o)
            assert np.max(np.abs(a_ref - a_rti)) < 0.01
            checked += 1
        else:
            rti.act(o)
    assert checked == 2


def test_fallback_counted_when_qp_fails(env, monkeypatch, short_run):
    *_, stream, _actions = short_run
    agent = env.possible_agents[0]
    pol = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 0))
    for o in stream[agent][:5]:
        pol.act(o)
    plan = pol.solver.abar.copy()

    def boom(*_args, **_kw):
        raise RuntimeError("QP solver failed (test)")

    monkeypatch.setattr(pol.solver, "solve_qp", boom)
    a = pol.act(stream[agent][5])
    assert pol.fallbacks == 1 and pol.stats["fallbacks"] == 1
    assert "fallback" in pol.stats["status"]
    np.testing.assert_allclose(a, plan[1])  # the shifted previous plan
    assert np.all(np.abs(a) <= 1)


def test_fallback_without_plan_holds(env, monkeypatch, short_run):
    *_, stream, _ = short_run
    pol = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 0))
    monkeypatch.setattr(pol.solver, "solve_qp", lambda: (_ for _ in ()).throw(RuntimeError()))
    a = pol.act(stream[env.possible_agents[0]][0])
    assert pol.fallbacks == 1 and a.shape == (8,) and np.all(np.isfinite(a))


def test_bad_observations_raise(env, short_run):
    *_, stream, _ = short_run
    pol = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 0))
    good = stream[env.possible_agents[0]][0]
    with pytest.raises(ValueError, match="shape"):
        pol.act(good[:-1])
    bad = good.copy()
    bad[OBSERVATION_STRUCTURE["zeta"].start + 2] = np.nan
    with pytest.raises(ValueError, match="zeta"):
        pol.act(bad)
    bad = good.copy()
    bad[OBSERVATION_STRUCTURE["waypoint"]] = 123.0
    with pytest.raises(ValueError, match="waypoint"):
        pol.act(bad)
    assert good.shape == (OBSERVATION_SIZE,)


@pytest.mark.slow
def test_paper_scenario_full():
    from nmpc_expert.distributed_episode import run_episode

    m, _, _ = run_episode("paper", progress=False)
    assert m["success"] and m["waypoints_in_order"]
    assert m["violation_periods"] == 0 and m["clean_success"], m
    assert m["min_manipulability"] > 0.5
    assert m["fallbacks"] == 0


def test_condensed_input_sensitivity_matches_finite_differences(env, short_run):
    """Gamma_0 = dx_1/da_0 read from the condensed QP equals central differences of the
    RK4 interval (the sensitivities drop small terms of the Jacobian of f: 5% slack)."""
    *_, stream, _ = short_run
    pol = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 0))
    for o in stream[env.possible_agents[0]][:10]:
        pol.act(o)
    gamma = pol.solver.input_sensitivity()
    x0, a0 = pol.solver.xbar[0].copy(), pol.solver.abar[0].copy()
    fd = np.zeros_like(gamma)
    for j in range(a0.size):
        e = np.zeros_like(a0)
        e[j] = 1e-4
        hi = pol.funcs.interval(x0, a0 + e, pol.theta)[0].full().ravel()
        lo = pol.funcs.interval(x0, a0 - e, pol.theta)[0].full().ravel()
        fd[:, j] = (hi - lo) / 2e-4
    assert np.linalg.norm(gamma - fd) < 0.05 * np.linalg.norm(fd)


def test_executed_hook_keeps_the_prediction_on_the_applied_input():
    """When another policy drives (DAgger), the expert is told the applied input; its
    one-step prediction of its own rates must then follow that input, not its own plan."""
    errors = {}
    for use_hook in (False, True):
        env = uvms_env.parallel_env(scenario="paper")
        obs, _ = env.reset(seed=0)
        pols = _policies(env)
        rng = np.random.default_rng(0)
        err = []
        for t in range(40):
            act = {a: p.act(obs[a]) for a, p in pols.items()}
            if t % 2:
                a0 = env.possible_agents[0]
                act[a0] = np.clip(act[a0] + 0.1 * rng.normal(size=8), -1, 1)
                if use_hook:
                    pols[a0].executed(act[a0])
            pred = pols[env.possible_agents[0]]._predicted_zeta.copy()
            obs, *_ = env.step(act)
            if t % 2:
                err.append(np.max(np.abs(obs[env.possible_agents[0]][10:20] - pred)))
        errors[use_hook] = float(np.mean(err))
    assert errors[True] < 0.7 * errors[False]
    with pytest.raises(ValueError, match="8 finite"):
        pols[env.possible_agents[0]].executed(np.full(8, np.nan))


def test_soft_rows_carry_the_l1_l2_slack_penalty(env, short_run):
    """DAQP's soft rows solve the same QP as explicit slacks s >= 0 with l1 s + l2 s^2
    (the IPOPT formulation), also when the rows cannot all hold: checked against IPOPT
    on the explicit-slack QP with the joint-rate bounds moved out of reach."""
    import casadi as cs

    *_, stream, _ = short_run
    # no input-step rows: the reference below has the box and the soft rows only
    pol = NMPCPolicy(
        AgentSpec.from_scenario(env.scenario, 0), settings=NMPCSettings(input_step=None)
    )
    for o in stream[env.possible_agents[0]][:10]:
        pol.act(o)
    solver = pol.solver
    h, f, c, lb, ub, lbc, ubc, *_ = (np.array(v) for v in solver._build.outputs)
    f, lb, ub, lbc, ubc = (v.ravel() for v in (f, lb, ub, lbc, ubc))
    joint_rates = [k for k, name in enumerate(CONSTRAINT_NAMES) if name.startswith("joint_speed")]
    rows = np.concatenate([np.array(joint_rates) + k * NC for k in range(solver.n)])
    # force violations: joint rates of 5x their limit, beyond what the saturated
    # inputs can reach within the horizon
    lbc[rows] += 5.0
    ubc[rows] = np.inf
    solver._build.outputs[5][...] = lbc.reshape(solver._build.outputs[5].shape)
    solver._build.outputs[6][...] = ubc.reshape(solver._build.outputs[6].shape)
    build = solver._build
    solver._build = lambda *a: build.outputs  # reuse the edited QP
    solver.input_offset[:] = 0.0  # the builder's own cost, as the reference QP below
    da, info = solver.solve_qp()
    assert info["slack_max"] > 1e-3  # the tightened rows are violated
    l1 = np.tile(pol.weights[WEIGHT_LAYOUT["slack_l1"]], solver.n)
    l2 = np.tile(pol.weights[WEIGHT_LAYOUT["slack_l2"]], solver.n)
    z, s = cs.SX.sym("z", da.size), cs.SX.sym("s", lbc.size)
    cost = 0.5 * cs.dot(z, cs.mtimes(cs.DM(h), z)) + cs.dot(cs.DM(f), z)
    cost += cs.dot(cs.DM(l1), s) + cs.dot(cs.DM(l2), s * s)
    cz = cs.mtimes(cs.DM(c), z)
    g = cs.vertcat(cz + s, cz - s)
    big = 1e20
    nlp = cs.nlpsol(
        "q",
        "ipopt",
        {"x": cs.vertcat(z, s), "f": cost, "g": g},
        {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-10},
    )
    sol = nlp(
        lbx=np.concatenate([lb, np.zeros(lbc.size)]),
        ubx=np.concatenate([ub, np.full(lbc.size, big)]),
        lbg=np.concatenate([lbc, np.full(lbc.size, -big)]),
        ubg=np.concatenate([np.full(lbc.size, big), np.minimum(ubc, big)]),
    )
    ref = sol["x"].full().ravel()[: da.size]
    np.testing.assert_allclose(da, ref, atol=1e-5)


def test_joint_position_penalty_changes_exactly_those_rows_penalties():
    """The joint-position rows' own (L1, L2): the weight vector differs from the default's
    in those rows' slack penalties and nowhere else; bad pairs are refused."""
    base = controller_weights(NMPCSettings())
    weights = controller_weights(NMPCSettings(joint_position_penalty=(0.0, 2.0)))
    rows = [k for k, name in enumerate(CONSTRAINT_NAMES) if name.startswith("joint_position")]
    l1, l2 = WEIGHT_LAYOUT["slack_l1"], WEIGHT_LAYOUT["slack_l2"]
    expected = {l1.start + k for k in rows} | {l2.start + k for k in rows}
    assert set(np.flatnonzero(weights != base)) == expected
    assert np.all(weights[l1][rows] == 0.0) and np.all(weights[l2][rows] == 2.0)
    for bad in ((1.0, 0.0), (-1.0, 1.0), (1.0,), (0.0, np.inf)):
        with pytest.raises(ValueError, match="joint_position_penalty"):
            NMPCSettings(joint_position_penalty=bad)  # type: ignore[arg-type]


def test_goal_integral_moves_the_reference_against_a_steady_offset(env):
    """Near the last waypoint the position reference moves opposite to the persistent
    object position error, by k_i * integral, clipped; elsewhere it is untouched."""
    spec = AgentSpec.from_scenario(env.scenario, 0)
    pol = NMPCPolicy(spec)
    s = pol.settings
    last = len(spec.waypoints) - 1
    err = np.array([0.2, -0.1, 0.0, 0.05, 0.0, -0.02])  # position and Euler-angle error
    x_o = spec.waypoints[last] + err
    for k in range(1, 4):
        expected = -s.goal_integral_gain * k * s.period * err
        np.testing.assert_allclose(pol.goal.shift(x_o, last), expected, atol=1e-12)
    for _ in range(10_000):  # windup is clipped
        pol.goal.shift(x_o, last)
    shift = np.abs(s.goal_integral_gain * pol.goal.integral)
    assert np.all(shift[:3] <= s.goal_integral_limit + 1e-12)
    assert np.all(shift[3:] <= s.goal_integral_angle_limit + 1e-12)
    pol.reset()
    assert not pol.goal.shift(x_o, 0).any()  # not the last waypoint: nothing happens
    far = x_o.copy()
    far[:3] += 1.0
    assert not pol.goal.shift(far, last).any()  # beyond the radius: no integration
    assert not pol.goal.integral.any()


def test_attitude_slew_moves_the_reference_at_its_rate_the_short_way():
    """``AttitudeSlew``: node k asks for a + clip(wrap(goal - a), +-rate k h) per Euler
    angle (across +-pi the short way), the twist reference's angular speed is capped at
    the rate and kept below it, ``a`` advances to node 1, reaches the goal and stays;
    ``reset`` starts again from the estimate."""
    rate, horizon, h = 0.1, 5, 0.12
    slew = AttitudeSlew(rate, horizon, h)
    goal = np.array([0.0, 0.01, 3.0])  # yaw 3.0 from -3.0: 0.283 rad the short way (down)
    x_o = np.array([1.0, 2.0, 0.5, 0.0, 0.0, -3.0])
    start = x_o[3:].copy()
    for period in range(40):
        xd = np.tile(np.r_[4.0, 5.0, 6.0, goal], (horizon + 1, 1))
        vd = np.zeros((horizon + 1, 6))
        vd[:, 3:] = [0.0, 0.003, 0.3]  # the navigation law's: faster than the rate
        vd[0, 3:] = [0.0, 0.0, 0.01]  # and slower
        slew.apply(xd, vd, x_o)
        np.testing.assert_array_equal(xd[:, :3], np.tile([4.0, 5.0, 6.0], (horizon + 1, 1)))
        a = start + np.clip(wrap_angle(goal - start), -rate * h * period, rate * h * period)
        for k in range(horizon + 1):
            step = rate * h * k
            expected = a + np.clip(wrap_angle(goal - a), -step, step)
            np.testing.assert_allclose(wrap_angle(xd[k, 3:] - expected), 0, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(vd[1:, 3:], axis=1), rate)
        np.testing.assert_allclose(vd[0, 3:], [0.0, 0.0, 0.01])  # below the rate: kept
    assert slew.attitude is not None
    np.testing.assert_allclose(wrap_angle(slew.attitude - goal), 0, atol=1e-12)  # 24 x 12 mrad
    assert slew.attitude[2] < -3.0  # went down through -pi, not up through 0
    slew.reset()
    xd = np.tile(np.r_[0, 0, 0, goal], (horizon + 1, 1))
    slew.apply(xd, np.zeros((horizon + 1, 6)), x_o)
    np.testing.assert_allclose(xd[0, 3:], start)


def test_attitude_tip_speed_slews_the_policys_reference_by_the_objects_size(env):
    """``attitude_tip_speed``: the distributed policy's rate is the tip speed over the
    object's bounding radius, its solver's attitude reference is the slew's; off (0, the
    default), or where the navigation law's own attitude rate is already no faster, the
    policy has none; bad values are refused by name. On the paper's team (its 0.93 m
    object: the slew is on below 0.047 m/s), whose policies the module builds anyway."""
    spec = AgentSpec.from_scenario(env.scenario, 0)
    radius = ObjectModel(spec.object_shape, spec.object_size).bounding_radius
    law = NMPCPolicy(spec).navigator.max_att_rate * radius  # the law's own tip speed
    assert NMPCPolicy(spec).slew is None
    assert NMPCPolicy(spec, settings=NMPCSettings(attitude_tip_speed=1.1 * law)).slew is None
    pol = NMPCPolicy(spec, settings=NMPCSettings(attitude_tip_speed=0.5 * law))
    assert pol.slew is not None and pol.slew.rate == pytest.approx(0.5 * law / radius)
    assert pol.slew.rate < pol.navigator.max_att_rate
    obs, _ = env.reset(seed=3)
    o = obs[env.possible_agents[0]]
    pol.act(o)
    first = pol.solver.xd[:, 3:].copy()
    waypoint = spec.waypoints[pol.stats["waypoint_index"], 3:]
    step = pol.slew.rate * pol.settings.period
    gap = np.abs(wrap_angle(waypoint - first[0]))
    assert gap.max() > first.shape[0] * step  # the slew binds on this start
    # node k is k steps nearer the waypoint's attitude, each angle at most its own gap
    for k in range(1, first.shape[0]):
        moved = np.abs(wrap_angle(first[k] - first[0]))
        np.testing.assert_allclose(moved, np.minimum(gap, k * step), atol=1e-12)
    pol.act(o)
    np.testing.assert_allclose(pol.solver.xd[0, 3:], first[1], atol=1e-12)
    for bad in ({"attitude_tip_speed": -0.1}, {"attitude_tip_speed": float("nan")}):
        with pytest.raises(ValueError, match="attitude_tip_speed"):
            NMPCSettings(**bad)
    with pytest.raises(ValueError, match="attitude_from_waypoint"):
        NMPCSettings(attitude_tip_speed=0.1, attitude_from_waypoint=False)


def test_constraint_names_are_the_rows_of_a_node(env):
    """``ocp.CONSTRAINT_NAMES`` names the NC soft rows of a node in the order the OCP
    stacks them: every row that is one entry of the local state (``CONSTRAINT_STATE``)
    has its unit Jacobian there, and the others (object pitch, manipulability) depend on
    the configuration q only."""
    spec = AgentSpec.from_scenario(env.scenario, 0)
    obj = ObjectModel(spec.object_shape, spec.object_key)
    outputs = build_outputs(build_local_model(default_model(), obj))
    x = np.random.default_rng(0).uniform(-0.3, 0.3, NX)
    jc = np.array(outputs(x, local_parameters(spec), np.zeros(6), np.zeros(6))[3])
    assert jc.shape == (NC, NX) and len(CONSTRAINT_NAMES) == len(CONSTRAINT_STATE) == NC
    for k, j in enumerate(CONSTRAINT_STATE):
        if j is None:
            assert CONSTRAINT_NAMES[k] in ("object_pitch", "manipulability")
            assert not jc[k, NX // 2 :].any() and jc[k, : NX // 2].any()
        else:
            assert np.array_equal(jc[k], np.eye(NX)[j]), CONSTRAINT_NAMES[k]
