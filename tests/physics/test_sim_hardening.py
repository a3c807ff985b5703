"""The truth simulator under abuse: the grasp holds at the end of every period, a period
that cannot be integrated accurately is refined or refused, divergence ends the episode on
the step it happens with finite values, and simulators and environments copy exactly."""

from __future__ import annotations

import copy
import pickle

import cloudpickle
import numpy as np
import pytest

import uvms_env
from uvms_env.env.infos import constraint_values, end_name
from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.sim.period import GRASP_TOL, SPEED_LIMITS
from uvms_env.sim.simulator import SimulationDiverged

BANG_BANG = [-1.0, 1.0]


def _returned_periods_hold_the_grasp(env, actions_for_step, steps: int) -> dict:
    """Step until the episode ends or ``steps``; assert every returned period's grasp
    error and finiteness. Returns the last infos of the first agent."""
    info: dict = {}
    for k in range(steps):
        obs, rew, _, _, infos = env.step(actions_for_step(k))
        pos, rot = env.sim.grasp_error()
        assert pos.max() <= GRASP_TOL and rot.max() <= GRASP_TOL, f"step {k}: {pos}, {rot}"
        values = np.concatenate([np.ravel(list(obs.values())), list(rew.values())])
        assert np.all(np.isfinite(values)), f"step {k}"
        assert max(abs(r) for r in rew.values()) < 1e3, f"step {k}: absurd reward {rew}"
        info = next(iter(infos.values()))
        if not env.agents:
            break
    return info


def test_grasp_held_every_period_in_the_bang_bang_episode_that_broke_it():
    """`short` seed 145 drifted 0.026 m at step 39 unflagged. The bar then turns to a
    vertical pitch, where the state's Euler angles are singular: the period is refused
    and the episode ends as diverged with that reason, never returning a bad state."""
    env = uvms_env.parallel_env("short")
    env.reset(seed=145)
    rng = np.random.default_rng(145)
    info = _returned_periods_hold_the_grasp(
        env, lambda k: {a: rng.choice(BANG_BANG, 8) for a in env.agents}, 300
    )
    assert end_name(info) == "diverged" and info["diverged"] == 1
    assert "singularity" in env.diverged_reason
    assert env.sim.refinements >= 1


@pytest.mark.parametrize(
    ("family", "overrides", "steps"),
    [
        ("paper", {"current": "strong", "sensor_noise": 1.0, "mismatch": 0.2}, 150),
        ("short", {"substeps": 1}, 60),
    ],
)
def test_grasp_held_every_period_under_saturated_bang_bang(family, overrides, steps):
    env = uvms_env.parallel_env(family, **overrides)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    _returned_periods_hold_the_grasp(
        env, lambda k: {a: rng.choice(BANG_BANG, 8) for a in env.agents}, steps
    )


@pytest.mark.parametrize(("substeps", "tolerance"), [(8, 1e-5), (1, 1e-3)])
def test_periods_agree_with_a_much_finer_integration(substeps, tolerance):
    """Against 16 parts of 8 substeps per period (through the same compiled function),
    after 10 periods: the default 8 substeps agree to 7e-7 (measured). One substep per
    period is too coarse for the arm's fast modes: the error control integrates every
    period in parts, which keeps it stable and on the manifold, though it checks the
    grasp residuals, not the full local error: 2e-4 (measured)."""
    sim = Simulator(make("short", substeps=substeps, seed=0))
    fine = Simulator(make("short", seed=0))
    rng = np.random.default_rng(0)
    h = np.array([sim.scenario.period / 16])
    for _ in range(10):
        tau = rng.uniform(-0.5, 0.5, (2, 8)) * sim.tau_max
        sim.step(tau)
        for _ in range(16):
            x_next, _, _ = fine._compiled_step()(
                fine.flat_state,
                tau,
                np.zeros(3),
                fine.parameters,
                fine.object_parameters,
                fine._grasp,
                h,
            )
            fine.flat_state[:] = x_next.reshape(-1)
    assert sim.refinements == (10 if substeps == 1 else 0)
    assert np.abs(sim.flat_state - fine.flat_state).max() < tolerance


def _constraint_jacobian(sim: Simulator) -> tuple[np.ndarray, np.ndarray]:
    """A (6N x 10N+6): grasp constraints in velocity coordinates; W: kinetic metric."""
    st, n = sim.state, sim.n
    a = np.zeros((6 * n, 10 * n + 6))
    w = np.zeros((10 * n + 6, 10 * n + 6))
    g_t = sim.grasp_matrix_t()
    for i in range(n):
        a[6 * i : 6 * i + 6, 10 * i : 10 * i + 10] = np.array(sim.uvms.ee_jacobian(st.q[i]))
        a[6 * i : 6 * i + 6, 10 * n :] = -g_t[:, 6 * i : 6 * i + 6].T
        w[10 * i : 10 * i + 10, 10 * i : 10 * i + 10] = np.array(
            sim.uvms.mass_matrix(st.q[i], sim.parameters[i])
        )
    w[10 * n :, 10 * n :] = np.array(
        sim.object.dynamics(st.x_O, st.v_O, np.zeros(3), sim.object_parameters)[0]
    )
    return a, w


def test_projection_lands_on_the_manifold_with_the_least_kinetic_energy_correction():
    sim = Simulator(make("paper"))
    rng = np.random.default_rng(2)
    for _ in range(20):
        sim.step(rng.uniform(-1, 1, (2, 8)) * sim.tau_max)
    n = sim.n
    x = sim.flat_state.copy()
    x[: 10 * n] += rng.normal(0, 1e-5, 10 * n)  # off the manifold by ~1e-5 m
    x[10 * n : 20 * n] += rng.normal(0, 1e-2, 10 * n)
    args = (sim.parameters.T, sim.object_parameters, sim._grasp.T)
    before = np.abs(np.vstack(sim.chain.grasp_error(x, sim._grasp.T)[:2])).max()
    projected = np.array(sim.chain.projection(x, *args)).ravel()
    pos, rot, twist = (np.array(e) for e in sim.chain.grasp_error(projected, sim._grasp.T))
    # one Newton step on the positions: the error is squared (measured: 2e-5 -> 1.3e-10)
    assert 1e-6 < before < 1e-4
    assert np.abs(np.vstack([pos, rot])).max() < 10 * before**2
    assert np.abs(twist).max() < 1e-12  # linear in the velocities: exact
    # velocities: the correction is W-orthogonal to the constraint's null space, i.e.
    # W dv lies in the range of A^T (KKT of min dv' W dv s.t. A (v + dv) = 0), with the
    # metric W of the integrated state and the constraints A of the projected one
    sim.flat_state[:] = x
    _, w = _constraint_jacobian(sim)
    sim.flat_state[:] = projected
    a, _ = _constraint_jacobian(sim)
    vel = np.r_[x[10 * n : 20 * n], x[20 * n + 6 :]]
    vel_new = np.r_[projected[10 * n : 20 * n], projected[20 * n + 6 :]]
    mu, *_ = np.linalg.lstsq(a.T, w @ (vel_new - vel), rcond=None)
    assert np.abs(a.T @ mu - w @ (vel_new - vel)).max() < 1e-9 * np.abs(w @ (vel_new - vel)).max()


@pytest.mark.parametrize("substeps", [8, 1])
def test_divergence_ends_the_episode_on_the_step_it_happens(substeps):
    """No damping and one held +-1 action: without divergence detection this returned a
    grasp error of 1.3e13 m and rewards of -1e14 (with substeps=1: inf observations)
    before any flag."""
    env = uvms_env.parallel_env("short", damping_scale=0.0, substeps=substeps)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(3)
    held = {a: rng.choice(BANG_BANG, 8) for a in env.agents}
    last_obs = obs
    for _ in range(300):
        obs, rew, term, _, infos = env.step(held)
        pos, rot = env.sim.grasp_error()
        assert pos.max() <= GRASP_TOL and rot.max() <= GRASP_TOL
        assert all(np.all(np.isfinite(o)) for o in obs.values())
        # bounded: at most the failure's price of the rest of the episode beyond 1e3
        bound = 1e3 + env.reward_weights.failure_penalty(env.max_cycles)
        assert all(np.isfinite(r) and abs(r) < bound for r in rew.values())
        if not env.agents:
            break
        last_obs = obs
    info = infos["uvms_0"]
    assert term["uvms_0"] and end_name(info) == "diverged"
    assert env.diverged_reason.startswith("the simulation diverged")
    # the refused step returns the last valid state: only the time fraction moved
    for a in obs:
        assert np.allclose(obs[a][:78], last_obs[a][:78], atol=1e-6)


def test_simulator_refuses_a_period_beyond_the_physical_envelope():
    sim = Simulator(make("paper", damping_scale=0.0))  # nothing slows the joints down
    rng = np.random.default_rng(0)
    for _ in range(10):
        sim.step(rng.uniform(-1, 1, (2, 8)) * sim.tau_max)
    st = sim.state
    # the grasps' velocity constraints are linear: scaled velocities still satisfy them,
    # here with joint rates beyond anything the saturations can produce
    scale = 1.5 * SPEED_LIMITS["joint"] / np.abs(st.zeta[:, 6:]).max()
    sim.set_state(st.q, st.zeta * scale, st.x_O, st.v_O * scale)
    before = sim.flat_state.copy()
    with pytest.raises(SimulationDiverged, match="speed"):
        sim.step(np.zeros((2, 8)))
    assert np.array_equal(sim.flat_state, before)  # the last valid state is kept


def _run(env, actions: list[dict]) -> list:
    out = []
    for a in actions:
        obs, rew, term, trunc, infos = env.step(a)
        out.append((obs, rew, term, trunc, {k: constraint_values(v) for k, v in infos.items()}))
    return out


@pytest.mark.parametrize(
    ("family", "overrides"),
    [
        ("paper", {"current": "mild", "sensor_noise": 1.0, "mismatch": 0.1}),
        ("random", {"n_agents": 3}),
    ],
)
def test_env_copies_continue_the_same_episode_bit_for_bit(family, overrides):
    env = uvms_env.parallel_env(family, **overrides)
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(10):
        env.step({a: rng.uniform(-1, 1, 8) for a in env.agents})
    copies = [
        pickle.loads(pickle.dumps(env)),
        cloudpickle.loads(cloudpickle.dumps(env)),
        copy.deepcopy(env),
        copy.copy(env),  # independent too: a shallow copy would share the simulator
    ]
    actions = [{a: rng.uniform(-1, 1, 8) for a in env.agents} for _ in range(15)]
    reference = _run(env, actions)
    for other in copies:
        assert other.sim is not env.sim
        for (o1, r1, t1, u1, g1), (o2, r2, t2, u2, g2) in zip(
            reference, _run(other, actions), strict=True
        ):
            assert all(np.array_equal(o1[a], o2[a]) for a in o1)
            assert r1 == r2 and t1 == t2 and u1 == u2 and g1 == g2
    # and the next seeded episode is the same too (seeders and geometry carried over)
    assert all(
        np.array_equal(env.reset(seed=9)[0][a], copies[0].reset(seed=9)[0][a])
        for a in env.possible_agents
    )


def test_simulator_pickles_mid_episode():
    sim = Simulator(make("paper", current="strong", mismatch=0.2, seed=4))
    rng = np.random.default_rng(4)
    for _ in range(5):
        sim.step(rng.uniform(-1, 1, (2, 8)) * sim.tau_max)
    twin = pickle.loads(pickle.dumps(sim))
    for _ in range(5):
        u = rng.uniform(-1, 1, (2, 8)) * sim.tau_max
        sim.step(u)
        twin.step(u)
    assert np.array_equal(sim.flat_state, twin.flat_state) and sim.t == twin.t


def test_single_precision_checks_its_periods_at_its_own_resolution():
    """float32 cannot hold a 1e-6 grasp error at positions of 10-50 m (their resolution is
    1-4 um): its error control's bounds are the float64 ones times
    ``FLOAT32_TOLERANCE_SCALE``, in the batched simulator's control and in the CUDA
    kernel's refinement alike; float64 keeps the model's."""
    from uvms_env.sim.period import (
        DRIFT_TOL_POSE,
        DRIFT_TOL_TWIST,
        FLOAT32_TOLERANCE_SCALE,
        PeriodControl,
        tolerances,
    )
    from uvms_env.vector.kernel_list import period_refinement

    assert tolerances(np.float64) == (DRIFT_TOL_POSE, DRIFT_TOL_TWIST, GRASP_TOL)
    single = tolerances(np.float32)
    assert single == pytest.approx(
        tuple(FLOAT32_TOLERANCE_SCALE * t for t in tolerances(np.float64))
    )
    assert np.spacing(np.float32(50.0)) > GRASP_TOL  # why: below float32's resolution
    bounds = PeriodControl(2, np, np.float32)._bounds[:, 0]
    assert bounds[:6] == pytest.approx(single[0]) and bounds[24:36] == pytest.approx(single[2])
    refine = period_refinement(2, "float32")
    assert (refine.tol_pose, refine.tol_twist, refine.grasp_tol) == pytest.approx(single)
    assert period_refinement(2).grasp_tol == GRASP_TOL
