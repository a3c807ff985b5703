"""Safety filter: a safe proposal passes unchanged, an unsafe one is corrected to a safe
prediction, locality (built from the robot's own spec and observation), fallback, and the
evaluator's ``+filter`` policies. Observations come from the environment."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import uvms_env
from baselines.evaluation.outputs import write_outputs
from baselines.evaluation.report import markdown_table
from baselines.evaluation.runner import evaluate
from baselines.loaders.sources import PolicySource, RandomPolicy
from nmpc_expert import NMPCPolicy, NMPCSettings, SafetyFilter
from uvms_env.dynamics.local_model import NX
from uvms_env.navigation import Workspace
from uvms_env.policy import AgentSpec, Policy

JOINT_RATES = slice(NX // 2 + 6, NX)  # the 4 joint rates in the model state [q; zeta]


class Constant:
    """A policy that always proposes the same action."""

    def __init__(self, action: np.ndarray) -> None:
        self.action = np.asarray(action, dtype=np.float64)
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.action.copy()


@pytest.fixture(scope="module")
def env():
    return uvms_env.parallel_env(scenario="paper")


def _spec(env, i: int) -> AgentSpec:
    return AgentSpec.from_scenario(env.scenario, i)


def _holding_input(env, obs) -> np.ndarray:
    """Robot 0's nominal holding input at the observed state (the expert's function)."""
    probe = SafetyFilter(_spec(env, 0), Constant(np.zeros(8)))
    probe._measure(obs)
    return np.clip(probe._hold(), -1.0, 1.0)


def _rollout_joint_rates(filt: SafetyFilter, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """Joint rates (N, 4) of the nonlinear local model driven by ``inputs`` from x0."""
    x, rates = x0.copy(), []
    for a in inputs:
        x = filt.funcs.interval(x, a, filt.theta)[0].full().ravel()
        rates.append(x[JOINT_RATES])
    return np.array(rates)


def test_expert_actions_pass_unchanged(env):
    """Around the expert's own actions: every period whose proposal (with the filter's
    backup tail) keeps all predicted constraints returns the proposal to 1e-6, and the
    others differ by less than the intervention tolerance (the expert rides its active
    constraints; the filter's node 1 is the exact model, the expert's plan linearized)."""
    obs, _ = env.reset(seed=0)
    filt = SafetyFilter(_spec(env, 0), NMPCPolicy(_spec(env, 0)))
    assert isinstance(filt, Policy)
    other = NMPCPolicy(_spec(env, 1))
    filt.reset()
    other.reset()
    safe = 0
    for _ in range(40):
        act = {"uvms_0": filt.act(obs["uvms_0"]), "uvms_1": other.act(obs["uvms_1"])}
        lbc, ubc = (filt.solver._build.outputs[k].ravel() for k in (5, 6))
        if lbc.max() <= 0.0 <= ubc.min():  # da = 0 keeps every soft row
            safe += 1
            assert filt.stats["intervention"] < 1e-6
        assert not filt.stats["intervened"]
        obs, *_ = env.step(act)
    assert safe >= 3
    assert filt.stats["fallbacks"] == 0 and filt.stats["interventions"] == 0


def test_unsafe_joint_torque_is_corrected_to_a_safe_prediction(env):
    """Full torque on joint 1, held: the model predicts the joint rate past its limit
    within the horizon. The filter changes it, its plan's nonlinear prediction keeps every
    joint rate within the limit, and in closed loop the joint-rate limit holds."""
    obs, _ = env.reset(seed=0)
    proposal = _holding_input(env, obs["uvms_0"])
    proposal[4] = 1.0  # joint 1 torque, normalized
    filt = SafetyFilter(_spec(env, 0), Constant(proposal))
    filt.reset()
    out = filt.act(obs["uvms_0"])
    x0 = filt._x0.copy()
    limit = filt.settings.joint_speed
    held = _rollout_joint_rates(filt, x0, np.tile(proposal, (filt.solver.n, 1)))
    assert np.abs(held).max() > limit  # unsafe as proposed
    assert filt.stats["intervened"] and np.abs(out - proposal).max() > 0.1
    planned = _rollout_joint_rates(filt, x0, filt.solver.abar)
    assert np.abs(planned).max() < limit

    # the teammate: the paper's controller (with the observer controller as teammate the
    # filtered robot overshot the joint-rate limit by 4% here: the filter has no observer)
    other = NMPCPolicy(_spec(env, 1), settings=NMPCSettings.paper())
    for filtered in (True, False):
        obs, _ = env.reset(seed=0)
        robot0 = filt if filtered else Constant(proposal)
        robot0.reset()
        other.reset()
        worst = -np.inf
        for _ in range(20):
            act = {"uvms_0": robot0.act(obs["uvms_0"]), "uvms_1": other.act(obs["uvms_1"])}
            obs, _, _, _, infos = env.step(act)
            worst = max(worst, infos["uvms_0"]["constraint_joint_speed"])
        assert (worst <= 0) == filtered, (filtered, worst)


def _barrier_after(filt: SafetyFilter, x0: np.ndarray, action: np.ndarray) -> np.ndarray:
    """The workspace barrier r (own bodies, object) [m/s] of the nonlinear local model one
    period after applying ``action`` from x0 (r <= 0: the prediction approaches the
    boundary no faster than the barrier allows)."""
    x1 = filt.funcs.interval(x0, action, filt.theta)[0].full().ravel()
    return filt.workspace_rows.values_at(x1)[0]


def test_workspace_rows_stop_an_outward_proposal(env):
    """The workspace's boundary placed 0.3 m / 0.21 m beyond the robot's outermost ball
    (its own bodies or the object), in the direction where one input pushes the object
    hardest; the team at rest (the barrier asks for 0.05 / 0.005 m/s inward at most).
    Holding, 0.3 m inside: the workspace rows change nothing. That input at full scale,
    filtered by the expert's rows alone, approaches the boundary faster than the barrier
    allows (r > 0); with the workspace rows the filter's input cuts r by more than 3/4 and
    its plan's nonlinear prediction stays inside."""
    obs, _ = env.reset(seed=0)
    spec = _spec(env, 0)
    probe = SafetyFilter(spec, Constant(np.zeros(8)))
    probe._measure(obs["uvms_0"])
    x0, hold = probe._x0.copy(), np.clip(probe._hold(), -1.0, 1.0)

    def object_velocity(a: np.ndarray) -> np.ndarray:
        x1 = probe.funcs.interval(x0, a, probe.theta)[0]
        return probe.funcs.object_state(x1, probe.theta)[1].full().ravel()[:3]

    # the strongest push of the object along u: each input at the saturation that moves
    # it along u, u the direction of the largest single-input effect
    base = object_velocity(hold)
    effects = []
    for k in range(8):
        a = hold.copy()
        a[k] = 1.0 if hold[k] < 0 else -1.0
        effects.append(object_velocity(a) - base)
    u = max(effects, key=lambda d: float(np.linalg.norm(d)))
    u /= np.linalg.norm(u)
    push = np.array(
        [np.sign(u @ d) * (1.0 if hold[k] < 0 else -1.0) for k, d in enumerate(effects)]
    )
    radius = 200.0  # a large ball: locally a plane with normal u
    centre = x0[:3] - radius * u
    shifted = dataclasses.replace(spec, workspace=Workspace(tuple(centre), radius))
    outermost = SafetyFilter(shifted, Constant(hold)).workspace_rows.values_at(x0)[1].max()
    for proposal, gap, unsafe in ((hold, 0.3, False), (push, 0.21, True)):
        # every ball moves by gap - outermost inward: the outermost sits gap inside
        near = dataclasses.replace(
            spec, workspace=Workspace(tuple(centre + (outermost + gap) * u), radius)
        )
        plain = SafetyFilter(near, Constant(proposal), workspace=False)
        filt = SafetyFilter(near, Constant(proposal))
        plain.reset()
        filt.reset()
        out_plain, out = plain.act(obs["uvms_0"]), filt.act(obs["uvms_0"])
        assert np.max(filt.workspace_rows.excess) < -0.2  # the plan's node 1, before the step
        before = _barrier_after(filt, filt._x0, out_plain)  # the expert's rows alone
        after = _barrier_after(filt, filt._x0, out)
        if not unsafe:  # inside the barrier: the rows change nothing
            assert before.max() < 0.0
            np.testing.assert_allclose(out, out_plain, atol=1e-9)
            continue
        assert before.max() > 0.01, before  # the pushing input: approaching too fast
        assert np.abs(out - out_plain).max() > 0.05
        # soft: the excess approach speed is cut by more than 3/4, not to zero (measured:
        # 0.056 to 0.012 m/s; its penalty, 100 per 0.1 m/s, is traded against the input
        # change)
        assert after.max() < 0.25 * before.max(), (before, after)
        x = filt._x0.copy()
        for a in filt.solver.abar:  # the plan's nonlinear prediction stays inside
            x = filt.funcs.interval(x, a, filt.theta)[0].full().ravel()
            assert filt.workspace_rows.values_at(x)[1].max() < 0.0


def test_replay_reproduces_outputs_no_shared_state(env):
    """Robot 1's filter, rebuilt alone from its spec and fed robot 1's recorded
    observations only, reproduces its outputs: nothing passes between the filters."""
    factory = PolicySource.parse("random+filter").factory(3)
    pols = {a: factory(_spec(env, i)) for i, a in enumerate(env.possible_agents)}
    for p in pols.values():
        p.reset()
    obs, _ = env.reset(seed=0)
    stream, outputs = [], []
    for _ in range(25):
        act = {a: p.act(obs[a]) for a, p in pols.items()}
        stream.append(obs["uvms_1"].copy())
        outputs.append(act["uvms_1"].copy())
        obs, *_ = env.step(act)
    assert pols["uvms_1"].stats["interventions"] > 0  # random proposals get corrected
    alone = SafetyFilter(_spec(env, 1), RandomPolicy(_spec(env, 1), 3))
    alone.reset()
    replay = np.array([alone.act(o) for o in stream])
    np.testing.assert_allclose(replay, np.array(outputs), atol=1e-9)


def test_failed_qp_falls_back_to_the_backup_plan(env, monkeypatch):
    obs, _ = env.reset(seed=0)
    filt = SafetyFilter(_spec(env, 0), Constant(_holding_input(env, obs["uvms_0"])))
    filt.reset()
    filt.act(obs["uvms_0"])
    backup = filt.solver.abar[1].copy()

    def boom(*_args, **_kw):
        raise RuntimeError("QP solver failed (test)")

    monkeypatch.setattr(filt.solver, "solve_qp", boom)
    out = filt.act(obs["uvms_0"])
    np.testing.assert_allclose(out, backup)
    assert filt.stats["fallbacks"] == 1 and "fallback" in filt.stats["status"]


def test_filter_suffix_parsing():
    src = PolicySource.parse("dagger:pretrained+filter")
    assert (src.name, src.arg, src.filtered, src.label) == (
        "dagger",
        "pretrained",
        True,
        "dagger:pretrained+filter",
    )
    assert PolicySource.parse("random+filter").filtered
    assert not PolicySource.parse("ppo:pretrained").filtered
    mod = PolicySource.parse("tests.evaluation.test_evaluate:raising_factory+filter")
    assert (mod.name, mod.arg, mod.filtered) == (
        "module",
        "tests.evaluation.test_evaluate:raising_factory",
        True,
    )
    with pytest.raises(ValueError, match="unknown policy"):
        PolicySource.parse("nonsense+filter")


def test_evaluator_reports_interventions_and_clean_success(tmp_path):
    rows = evaluate(
        ["random+filter", "zero"], ["short"], 1, 0, workers=1, max_cycles=5, progress=False
    )
    filtered, plain = rows
    assert filtered["error"] == "" and filtered["filtered_decisions"] == 10
    assert 0.0 < filtered["intervention_rate"] <= 1.0
    assert plain["intervention_rate"] is None and plain["clean_success"] is False
    summaries = write_outputs(rows, 0, tmp_path)
    assert summaries[0]["intervention_rate"] == filtered["intervention_rate"]
    assert summaries[1]["intervention_rate"] is None
    assert "clean_success_rate" in summaries[0]
    assert "intervention rate" in markdown_table(summaries)
