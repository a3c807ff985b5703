"""Safety filter's input-step bound (``max_input_step``): a proposal far from the input
applied last period is moved to within the bound of it (first input and the plan's tail),
an outer driver's input (``executed``) is the reference, and without the bound the filter
is unchanged. Observations come from the environment."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import uvms_env
from baselines.loaders.sources import RandomPolicy
from nmpc_expert import NMPCPolicy, SafetyFilter
from uvms_env.policy import AgentSpec

STEP = 0.05
TOL = 1e-6  # the QP's feasibility tolerance on hard bounds (normalized inputs)


class Alternating:
    """Proposes +1 and -1 on every input in turn: each proposal is 2 away from the last."""

    def __init__(self) -> None:
        self.sign = 1.0
        self.stats: dict = {}

    def reset(self) -> None:
        self.sign = 1.0

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.sign = -self.sign
        return np.full(8, self.sign)


@pytest.fixture(scope="module")
def env():
    return uvms_env.parallel_env(scenario="paper")


def _spec(env, i: int) -> AgentSpec:
    return AgentSpec.from_scenario(env.scenario, i)


def _rollout(env, robot0, steps: int) -> list[np.ndarray]:
    """Robot 0 driven by ``robot0``, robot 1 by the expert; robot 0's outputs."""
    other = NMPCPolicy(_spec(env, 1))
    obs, _ = env.reset(seed=0)
    robot0.reset()
    other.reset()
    outputs = []
    for _ in range(steps):
        act = {"uvms_0": robot0.act(obs["uvms_0"]), "uvms_1": other.act(obs["uvms_1"])}
        outputs.append(act["uvms_0"].copy())
        obs, *_ = env.step(act)
    return outputs


def test_far_proposal_is_moved_within_the_step_of_the_last_input(env):
    filt = SafetyFilter(_spec(env, 0), Alternating(), max_input_step=STEP)
    outputs = _rollout(env, filt, 12)
    assert filt.stats["fallbacks"] == 0
    for prev, out in itertools.pairwise(outputs):
        assert np.abs(out - prev).max() <= STEP + TOL
        assert np.all(np.abs(out) <= 1.0)
    # the proposals (all +1 or all -1) are 2 apart: the filter intervened every period
    assert filt.stats["interventions"] == filt.stats["decisions"]
    # the plan's tail keeps the same bound (the backup plan is one the robot may follow)
    plan = filt.solver.abar
    assert np.abs(plan[0] - outputs[-1]).max() < 1e-12
    assert np.abs(np.diff(plan, axis=0)).max() <= STEP + TOL

    # an outer driver's input is the reference of the next period
    applied = np.clip(outputs[-1] + 0.5, -1.0, 1.0)
    filt.executed(applied)
    obs, _ = env.reset(seed=0)
    out = filt.act(obs["uvms_0"])
    assert np.abs(out - applied).max() <= STEP + TOL


def test_a_proposal_within_the_step_passes_unchanged(env):
    """A bound wider than the input box (2) never binds: the same outputs as without it,
    to the QP's accuracy; with ``max_input_step=None`` the QP has no step rows at all."""
    plain = SafetyFilter(_spec(env, 0), RandomPolicy(_spec(env, 0), 3))
    wide = SafetyFilter(_spec(env, 0), RandomPolicy(_spec(env, 0), 3), max_input_step=2.5)
    assert plain.solver.max_step is None
    n, nz = plain.solver.n, plain.solver._nz
    assert len(plain.solver._sense) == nz + plain.solver._nsoft  # today's QP layout
    assert len(wide.solver._sense) == nz + wide.solver._nsoft + 8 * (n - 1)
    a = _rollout(env, plain, 25)
    b = _rollout(env, wide, 25)
    np.testing.assert_allclose(np.array(b), np.array(a), atol=1e-6)


def test_invalid_step_is_rejected(env):
    with pytest.raises(ValueError, match="max_input_step"):
        SafetyFilter(_spec(env, 0), Alternating(), max_input_step=0.0)
