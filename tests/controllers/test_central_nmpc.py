"""The centralized NMPC (``nmpc_expert.central``) and the team-policy interface
(``uvms_env.team_policy``, ``uvms_env.episode.play_team``): its prediction model is the
simulator's team dynamics, team and per-robot policies cannot be mixed up, the evaluator
marks its rows as full-information bounds, it predicts with the model it is handed, its
soft rows are the expert's, and it carries the object to the goal."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import uvms_env
from baselines.evaluation.report import markdown_table
from baselines.evaluation.runner import evaluate
from baselines.evaluation.summary import aggregate
from baselines.loaders.sources import PolicySource
from nmpc_expert import central as central_module
from nmpc_expert.central import CentralNMPC, central_settings, make_central_policy
from nmpc_expert.ocp import CONSTRAINT_NAMES, build_outputs
from nmpc_expert.team_model import TeamModel
from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.local_model import build_local_model
from uvms_env.dynamics.uvms import default_model
from uvms_env.episode import TEAM, build_policies, play, play_team
from uvms_env.policy import AgentSpec
from uvms_env.scenarios import make
from uvms_env.sim.simulator import Simulator
from uvms_env.team_policy import FULL_INFORMATION, TeamPolicyFactory


class _StillTeam:
    """A team policy that applies no input (no compilation: the interface tests)."""

    information = FULL_INFORMATION

    def __init__(self, scenario) -> None:
        self.n = scenario.n_agents
        self.stats: dict[str, Any] = {}
        self.states: list[np.ndarray] = []

    def reset(self) -> None:
        self.states.clear()

    def act(self, state: np.ndarray) -> np.ndarray:
        self.states.append(np.array(state))
        return np.zeros((self.n, 8))


class _Zero:
    def __init__(self, spec) -> None:
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    def act(self, obs):
        return np.zeros(8, np.float32)


@pytest.fixture(scope="module")
def short_scenario():
    return make("short", seed=202)


@pytest.fixture(scope="module")
def controller(short_scenario):
    return CentralNMPC(short_scenario)


def test_the_prediction_model_is_the_simulators_team_dynamics(short_scenario, controller):
    """Same state, same inputs, nominal parameters, one period: the controller's
    prediction and the truth simulator agree to 1e-9, on states along random motion."""
    sim = Simulator(short_scenario)
    sim.parameters = sim.nominal_parameters.copy()
    sim.object_parameters = sim.nominal_object_parameters.copy()
    rng = np.random.default_rng(7)
    compared = 0
    for _ in range(12):
        a = rng.uniform(-1, 1, (sim.n, 8))
        x = sim.flat_state.copy()
        predicted = controller.model.predict(x, a)
        before = sim.refinements
        sim.step(a * controller.model.tau_max)
        if sim.refinements == before:  # a refined period is integrated in parts
            assert np.abs(predicted - sim.flat_state).max() <= 1e-9
            compared += 1
    assert compared >= 10
    assert np.abs(sim.state.zeta).max() > 1e-3  # the states moved: not only rest


def test_the_input_reference_is_each_robots_steady_input_of_the_expert(controller):
    """R pulls every robot towards its own a_ss (its grasp, its load share), the same
    input reference as the distributed expert's cost."""
    sim = Simulator(controller.scenario)
    x = sim.flat_state.copy()
    n, hz = controller.n, controller.horizon
    twists = np.tile([0.1, -0.05, 0.0, 0.0, 0.0, 0.02], (hz, 1))
    solver = controller.solver
    a_ss = solver.steady_inputs(np.tile(x, (hz, 1)), twists)
    for i in range(n):
        x_i = np.r_[x[10 * i : 10 * i + 10], x[10 * n + 10 * i : 10 * n + 10 * i + 10]]
        own = np.array(solver._steady_fn(x_i, solver.theta[i], twists[0])).ravel()
        assert np.allclose(a_ss[:, i], own, atol=1e-12)
    assert not np.allclose(a_ss[0, 0], a_ss[0, 1])  # the robots' grasps differ


def test_the_team_rows_are_every_robots_expert_constraints(controller):
    """At a node of the plan the team QP's soft rows are, robot by robot, the expert's
    soft constraint values of that robot's local model (``ocp.CONSTRAINT_NAMES``), and
    the object's pitch once."""
    sim = Simulator(controller.scenario)
    rng = np.random.default_rng(3)
    for _ in range(3):
        sim.step(rng.uniform(-1, 1, (sim.n, 8)) * controller.model.tau_max)
    x = sim.flat_state.copy()
    n, nx, solver = controller.n, controller.nx, controller.solver
    solver.reset()
    solver.shift(x, np.zeros((n, 8)))
    lin = controller.model.linearize(solver.xbar, solver.abar)
    gk, ek = np.zeros((nx, solver.n * controller.nu)), np.zeros(nx)
    values = solver._node_rows(1, gk, ek, lin)[1] * solver._scale
    solver.reset()
    scenario = controller.scenario
    obj = ObjectModel(scenario.object_shape, scenario.object_key)
    outputs = build_outputs(build_local_model(default_model(), obj))
    pitch = CONSTRAINT_NAMES.index("object_pitch")
    own = [k for k in range(len(CONSTRAINT_NAMES)) if k != pitch]
    rows = len(own)
    for i in range(n):
        x_i = np.r_[x[10 * i : 10 * i + 10], x[10 * n + 10 * i : 10 * n + 10 * i + 10]]
        c = np.array(outputs(x_i, solver.theta[i], np.zeros(6), np.zeros(6))[2]).ravel()
        np.testing.assert_allclose(values[rows * i : rows * (i + 1)], c[own], rtol=1e-9)
        assert abs(values[-1] - c[pitch]) < 1e-5  # the grasps hold to the simulator's 1e-6
    assert len(values) == rows * n + 1


def test_the_controller_predicts_with_the_model_it_is_handed():
    """By default the nominal model, whatever the truth draws; a ``TeamModel`` at other
    parameters (here the mismatched truth's) is what the controller then predicts with;
    one of another horizon is refused."""
    scenario = make("short", seed=202, mismatch=0.2)
    team = CentralNMPC(scenario)
    sim = Simulator(scenario)
    assert np.array_equal(team.model.parameters, sim.nominal_parameters)
    assert np.array_equal(team.model.object_parameters, sim.nominal_object_parameters)
    assert not np.array_equal(sim.parameters, sim.nominal_parameters)  # the truth differs
    horizon = central_settings().horizon
    truth = TeamModel(scenario, horizon, sim.parameters, sim.object_parameters)
    team = CentralNMPC(scenario, model=truth)
    a = np.full((sim.n, 8), 0.3)
    predicted = team.model.predict(sim.flat_state.copy(), a)
    sim.step(a * truth.tau_max)
    assert sim.refinements == 0 and np.abs(predicted - sim.flat_state).max() <= 1e-9
    with pytest.raises(ValueError, match="the controller needs"):
        CentralNMPC(scenario, central_settings(horizon=horizon - 1), model=truth)


def test_team_and_per_robot_policies_cannot_be_mixed_up():
    env = uvms_env.parallel_env("short", max_cycles=3)
    team = TeamPolicyFactory(_StillTeam, "still")
    with pytest.raises(TypeError, match="play_team"):
        play(env, team, seed=0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="per-robot factory"):
        play_team(env, _Zero, seed=0)  # type: ignore[arg-type]
    env.reset(seed=0)
    with pytest.raises(TypeError, match="team policy"):
        build_policies(env, _StillTeam)  # a bare callable building a team policy
    with pytest.raises(TypeError, match="takes the Scenario"):
        team(AgentSpec.from_scenario(env.scenario, 0))  # type: ignore[arg-type]
    source = PolicySource.parse("nmpc:central")
    assert source.team and source.information == "full"
    assert not PolicySource.parse("nmpc").team
    with pytest.raises(TypeError, match="team policy"):
        source.factory(0)
    with pytest.raises(TypeError, match="per-robot"):
        PolicySource.parse("nmpc").team_factory(0)
    with pytest.raises(ValueError, match="safety filter"):
        PolicySource.parse("nmpc:central+filter")


def test_play_team_sees_the_global_state_and_times_team_decisions():
    env = uvms_env.parallel_env("short", max_cycles=4)
    episode = play_team(env, TeamPolicyFactory(_StillTeam), seed=0)
    team = episode.policies[TEAM]
    assert episode.steps == 4 and episode.decision_ms.shape == (4, 1)
    assert len(team.states) == 4 and team.states[0].shape == env.state().shape
    assert episode.metrics["policy_time_ms_max"] == pytest.approx(episode.decision_ms.max())
    # the same loop as per-robot play: zero inputs give the same episode either way
    alone = play(uvms_env.parallel_env("short", max_cycles=4), _Zero, seed=0)
    assert episode.metrics["control_effort"] == alone.metrics["control_effort"]
    assert episode.metrics["return"] == alone.metrics["return"]


def test_bad_state_is_a_clear_error_and_a_failed_solve_falls_back(monkeypatch):
    env = uvms_env.parallel_env("short", seed=202)
    env.reset(seed=202)
    state = env.state()
    controller = CentralNMPC(env.scenario)
    controller.reset()
    with pytest.raises(ValueError, match="shape"):
        controller.act(state[:-1])
    bad = state.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        controller.act(bad)

    def broken(*args, **kwargs):
        raise RuntimeError("solver down")

    monkeypatch.setattr(controller.solver, "solve_qp", broken)
    first = controller.act(state)  # no plan yet: the steady inputs at rest
    assert first.shape == (2, 8) and np.all(np.abs(first) <= 1)
    assert controller.stats["status"].startswith("fallback") and controller.fallbacks == 1
    monkeypatch.undo()
    controller.act(state)
    plan = controller.solver.abar[1].copy()
    monkeypatch.setattr(controller.solver, "solve_qp", broken)
    shifted = controller.act(state)  # the previous plan, shifted
    assert np.allclose(shifted, plan) and controller.fallbacks == 2


def test_the_evaluator_marks_team_rows_as_full_information():
    rows = evaluate(
        ["nmpc:central", "nmpc"], ["short"], 1, 202, workers=1, max_cycles=30, progress=False
    )
    by_policy = {r["policy"]: r for r in rows}
    assert not any(r["error"] for r in rows), [r["error"] for r in rows]
    assert by_policy["nmpc:central"]["information"] == "full"
    assert by_policy["nmpc"]["information"] == "local"
    assert by_policy["nmpc:central"]["episode_steps"] == 30
    # one time per team decision, one per agent decision for the per-robot expert
    assert len(by_policy["nmpc:central"]["_decision_ms"]) == 30
    assert len(by_policy["nmpc"]["_decision_ms"]) == 60
    # the squeeze is in the team's cost and out of every robot's reach
    squeeze = {p: r["internal_wrench_rms"] for p, r in by_policy.items()}
    assert squeeze["nmpc:central"] < squeeze["nmpc"]
    table = markdown_table(aggregate(rows, 202))
    assert "| nmpc:central | full | short |" in table
    assert "| nmpc | local | short |" in table
    assert "full-information reference" in table


def test_the_central_controller_carries_the_object_to_the_goal(short_scenario):
    """A whole ``short`` episode: the object reaches the goal within the task's tolerance,
    no decision fell back."""
    env = uvms_env.parallel_env("short", seed=202)
    episode = play_team(env, make_central_policy(), seed=202)
    team = episode.policies[TEAM]
    assert episode.metrics["success"]
    assert episode.metrics["final_pos_error_m"] <= short_scenario.success_pos_tol
    assert team.fallbacks == 0


class _Recording(CentralNMPC):
    """The centralized NMPC, keeping the states it saw and the actions it took."""

    def __init__(self, scenario) -> None:
        super().__init__(scenario)
        self.seen: list[tuple[np.ndarray, np.ndarray]] = []

    def act(self, state: np.ndarray) -> np.ndarray:
        action = super().act(state)
        self.seen.append((np.array(state[: self.nx]), action))
        return action


def test_the_disturbance_estimate_is_the_prediction_error_it_filters():
    """With the truth at the nominal parameters and no current the one-period prediction
    error is round-off (the env's float32 actions, refined periods), so the estimate stays
    near zero; under mismatch it is the filtered error of the model, recomputed here from
    the states the controller saw, and orders of magnitude larger."""
    largest = {}
    for mismatch in (0.0, 0.2):
        env = uvms_env.parallel_env("short", seed=202, mismatch=mismatch, max_cycles=6)
        episode = play_team(env, TeamPolicyFactory(_Recording), seed=202)
        team = episode.policies[TEAM]
        expected = np.zeros(team.nx)
        for (x0, a0), (x1, _) in zip(team.seen, team.seen[1:], strict=False):
            error = x1 - team.model.predict(x0, a0)
            error[team._angles] = (error[team._angles] + np.pi) % (2 * np.pi) - np.pi
            expected += central_module.DISTURBANCE_GAIN * (error - expected)
        assert np.allclose(team.disturbance, expected, atol=1e-12)
        largest[mismatch] = np.abs(team.disturbance).max()
    assert largest[0.0] < 1e-6
    assert largest[0.2] > 100 * largest[0.0]
