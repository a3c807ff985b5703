"""The OCP's compiled library: one for every object of a strip capacity, and the same QP as
CasADi's own evaluation of the symbolic OCP.

The reference is ``OCPFunctions.qp_builder_graph``, the symbolic builder (the interval's
RK4 and sensitivities, the nodes' terms and the condensing as one CasADi graph, its
Jacobians CasADi's automatic derivatives) evaluated by CasADi's virtual machine,
uncompiled: nothing of the library's C (the driver's loops, its Cholesky solves, the
Jacobian split of the object's drag) is in it.

Fast: the library is compiled once per machine (cached), the reference runs on the
virtual machine in a second or so per QP.
"""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from nmpc_expert import NMPCPolicy
from nmpc_expert.local_controller import object_capacity
from nmpc_expert.ocp import build_stage_functions, library_source, library_tag, ocp_functions
from nmpc_expert.settings import FILTER_HORIZON, LIBRARY_HORIZONS
from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compiler_off
from uvms_env.dynamics.local_model import GRASP_THETA, build_steady_input
from uvms_env.dynamics.uvms import default_model
from uvms_env.policy import AgentSpec

SCENARIOS = {"bar": {"scenario": "paper"}, "ring": {"scenario": "random", "seed": 7}}


@pytest.fixture(scope="module")
def policies():
    """A robot of the paper's bar and one of a ring, each after two decisions from the
    start (the second around a shifted plan)."""
    out = {}
    for name, kwargs in SCENARIOS.items():
        env = uvms_env.parallel_env(**kwargs)
        obs, _ = env.reset(seed=0)
        agent = env.possible_agents[0]
        pol = NMPCPolicy(AgentSpec.from_scenario(env.scenario, 0))
        for _ in range(2):
            pol.act(obs[agent])
            obs, *_ = env.step({a: np.zeros(8) for a in env.possible_agents})
        out[name] = pol
    return out


def _as_casadi(inputs: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    """The builder's numpy inputs (CasADi's column-major layout, transposed) as CasADi
    takes matrices."""
    return [a.T if a.ndim == 2 else a for a in inputs]


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_the_compiled_qp_is_casadis_evaluation_of_the_symbolic_one(policies, name):
    """H, f, the soft rows and their bounds, the condensed dynamics G, e and the input
    reference, from the library around a robot's plan, equal the symbolic builder's on
    CasADi's virtual machine to 1e-9 of each output's size (round-off of the different
    writings of the same sums; the bounds of no limit stay infinite)."""
    pol = policies[name]
    funcs = pol.funcs
    if compiler_off():
        pytest.skip("no compiler: the library is the symbolic builder itself")
    inputs = pol.solver.build_inputs()
    compiled = BufferCall(funcs.qp_builder)(*inputs)
    reference = funcs.qp_builder_graph(*_as_casadi(inputs))
    names = [funcs.qp_builder.name_out(i) for i in range(funcs.qp_builder.n_out())]
    for out_name, mine, ref in zip(names, compiled, reference, strict=True):
        ref = np.asarray(ref).ravel(order="F")
        mine = mine.reshape(-1)
        finite = np.isfinite(ref)
        np.testing.assert_array_equal(np.isfinite(mine), finite, err_msg=out_name)
        np.testing.assert_array_equal(mine[~finite], ref[~finite], err_msg=out_name)
        scale = max(np.abs(ref[finite]).max(), 1e-12)
        np.testing.assert_allclose(
            mine[finite], ref[finite], rtol=0, atol=1e-9 * scale, err_msg=out_name
        )
    # the object matters: the ring's parameters in the bar robot's QP change it
    other = policies["ring" if name == "bar" else "bar"]
    theta = np.r_[pol.theta[:GRASP_THETA], other.theta[GRASP_THETA:]]
    swapped = (*inputs[:2], theta, *inputs[3:])
    moved = BufferCall(funcs.qp_builder)(*swapped)
    assert np.abs(moved[0] - compiled[0]).max() > 1e-6 * np.abs(compiled[0]).max()


def test_the_policy_functions_are_the_local_models(policies):
    """The library's steady input and object estimate (what the policy calls outside the
    QP) equal the symbolic local model's on CasADi's virtual machine."""
    for pol in policies.values():
        funcs = pol.funcs
        x, vd = pol.solver.xbar[1], pol.solver.vd[1]
        obj = ObjectModel.of_capacity(funcs.capacity)
        reference = build_steady_input(default_model(), obj, funcs.model)(x, pol.theta, vd)
        np.testing.assert_allclose(
            np.asarray(funcs.steady_input(x, pol.theta, vd)), np.asarray(reference), atol=1e-12
        )
        for mine, ref in zip(
            funcs.object_state(x, pol.theta), funcs.model.object_state(x, pol.theta), strict=True
        ):
            np.testing.assert_allclose(np.asarray(mine), np.asarray(ref), atol=1e-12)


def test_one_library_serves_the_bar_and_every_ring(policies):
    """The paper's bar and a ring share the OCP functions (one library, built and compiled
    once), and the library's C is the same whichever object of the capacity builds it:
    nothing of the object is in its code. Longer bars have their capacity's library."""
    bar, ring = policies["bar"], policies["ring"]
    assert bar.funcs is ring.funcs
    assert object_capacity(bar.spec) == object_capacity(ring.spec) == bar.funcs.capacity
    uvms = default_model()
    tag = library_tag(1, 0.12, 2)
    sources = {
        library_source(uvms, build_stage_functions(uvms, obj, tag), (2,), 0.12, 2, tag)
        for obj in (ObjectModel("ring", 0.7), ObjectModel("bar", 3.4))
    }
    assert len(sources) == 1
    assert ObjectModel("bar", 8.2).capacity != bar.funcs.capacity
    s = bar.settings
    args = (bar.funcs.capacity, s.horizon, s.period, s.substeps, LIBRARY_HORIZONS)
    assert ocp_functions(*args) is bar.funcs


def _truncated(inputs: tuple[np.ndarray, ...], horizon: int) -> tuple[np.ndarray, ...]:
    """The builder's inputs of a longer plan cut to ``horizon`` intervals: the first nodes
    of xbar, xd and vd, the first inputs of abar."""
    xbar, abar, theta, xd, vd, w, d = inputs
    nodes = slice(0, horizon + 1)
    return xbar[nodes], abar[:horizon], theta, xd[nodes], vd[nodes], w, d


def test_the_filters_horizon_is_in_the_experts_library(policies):
    """The safety filter's horizon and the expert's share one compiled library (one
    source, one file), and its horizon-3 entry is the symbolic builder of horizon 3 on
    the expert's plan cut to three intervals, to 1e-9 of each output's size."""
    if compiler_off():
        pytest.skip("no compiler: the library is the symbolic builder itself")
    pol = policies["bar"]
    s, cap = pol.settings, pol.funcs.capacity
    short = ocp_functions(cap, FILTER_HORIZON, s.period, s.substeps, LIBRARY_HORIZONS)
    assert short.source == pol.funcs.source
    assert short.qp_builder.name() != pol.funcs.qp_builder.name()
    inputs = _truncated(pol.solver.build_inputs(), FILTER_HORIZON)
    compiled = BufferCall(short.qp_builder)(*(np.ascontiguousarray(a) for a in inputs))
    reference = short.qp_builder_graph(*_as_casadi(inputs))
    for mine, ref in zip(compiled, reference, strict=True):
        ref = np.asarray(ref).ravel(order="F")
        finite = np.isfinite(ref)
        scale = max(np.abs(ref[finite]).max(), 1e-12)
        np.testing.assert_allclose(mine.reshape(-1)[finite], ref[finite], atol=1e-9 * scale)
