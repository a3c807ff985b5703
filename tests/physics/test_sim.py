"""Properties of the closed-chain truth simulator."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.sim.period import ENVELOPE, INACCURATE, OK, SPEED_LIMITS, PeriodControl

MIRROR_Q = np.array([1, -1, 1, -1, 1, -1, -1, 1, 1, -1], dtype=float)  # y -> -y reflection
MIRROR_TAU = np.array([1, -1, 1, -1, -1, 1, 1, -1], dtype=float)
MIRROR_OBJ = np.array([1, -1, 1, -1, 1, -1], dtype=float)


def test_start_satisfies_grasps_and_holding_is_feasible(paper):
    sim = Simulator(paper)
    pos, rot = sim.grasp_error()
    assert pos.max() < 1e-9 and rot.max() < 1e-9
    tau = sim.holding_inputs()
    assert np.all(np.abs(tau) <= sim.tau_max)
    x_dot = np.array(
        sim.chain.rhs(
            sim.flat_state,
            tau.T,
            np.zeros(3),
            sim.parameters.T,
            sim.object_parameters,
            sim._grasp.T,
        )
    ).ravel()
    assert np.abs(x_dot).max() < 1e-9  # at rest and not accelerating: a static equilibrium


def test_energy_conserved_without_damping():
    """Damping off, no current, zero input: the chain collapses under its weights (arms
    limp) and swings for 60 s; total energy drifts < 0.5% of the kinetic energy reached."""
    sim = Simulator(make("paper", damping_scale=0.0))
    e0 = sim.energy()
    drift, kinetic = 0.0, 0.0
    for _ in range(500):
        sim.step(np.zeros((2, 8)))
        e = sim.energy()
        st = sim.state
        ke = e - sum(
            float(sim.uvms.potential(q, p)) for q, p in zip(st.q, sim.parameters, strict=True)
        )
        ke -= float(sim.object.energy(st.x_O, np.zeros(6), sim.object_parameters))
        kinetic = max(kinetic, ke)
        drift = max(drift, abs(e - e0))
    assert kinetic > 0.1  # it really moved
    assert drift < 0.005 * kinetic


def test_energy_never_increases_with_damping_and_no_input():
    sim = Simulator(make("paper"))
    e_prev = sim.energy()
    for _ in range(300):
        sim.step(np.zeros((2, 8)))
        e = sim.energy()
        assert e <= e_prev + 1e-9
        e_prev = e


def test_grasp_drift_tiny_under_random_saturated_inputs():
    sim = Simulator(make("paper"))
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(2000):
        sim.step(rng.choice([-1.0, 1.0], (2, 8)) * rng.uniform(1.0, 1.5) * sim.tau_max)
        pos, rot = sim.grasp_error()
        worst = max(worst, pos.max())
        assert np.all(np.isfinite(sim.flat_state)) and rot.max() < 1e-5
    assert worst < 1e-6


def test_saturation_applied_and_reported(paper):
    sim = Simulator(paper)
    tau = np.zeros((2, 8))
    tau[0, 0], tau[1, 7] = 50.0, -3.0
    info = sim.step(tau)
    assert info.tau_applied[0, 0] == sim.tau_max[0] and info.tau_applied[1, 7] == -sim.tau_max[7]
    assert info.saturated.sum() == 2 and info.saturated[0, 0] and info.saturated[1, 7]


def _mirror_state(sim: Simulator) -> tuple:
    st = sim.state
    return st.q[::-1] * MIRROR_Q, st.zeta[::-1] * MIRROR_Q, st.x_O * MIRROR_OBJ, st.v_O * MIRROR_OBJ


def test_mirror_symmetry(uvms, rng):
    # the joint sign pattern is the reflection of the arm's kinematics
    for _ in range(5):
        q = rng.uniform(-1, 1, 10)
        p, _ = uvms.ee_pose(q)
        pm, _ = uvms.ee_pose(q * MIRROR_Q)
        assert np.allclose(np.array(pm).ravel(), np.array(p).ravel() * [1, -1, 1], atol=1e-9)
    scenario = make("paper")
    a, b = Simulator(scenario), Simulator(scenario)
    b.set_state(*_mirror_state(a))
    for _ in range(100):
        u = rng.uniform(-1, 1, (2, 8)) * a.tau_max
        a.step(u)
        b.step(u[::-1] * MIRROR_TAU)
    q, zeta, x_o, v_o = _mirror_state(a)
    st = b.state
    assert np.allclose(st.q, q, atol=1e-8) and np.allclose(st.zeta, zeta, atol=1e-8)
    assert np.allclose(st.x_O, x_o, atol=1e-8) and np.allclose(st.v_O, v_o, atol=1e-8)


@pytest.mark.parametrize(
    ("tau", "message"),
    [
        (np.full((2, 8), np.nan), "NaN"),
        (np.array([[0, 0, 0, 0, 0, 0, 0, np.inf]] * 2), "NaN or inf"),
        (np.zeros((3, 8)), "shape"),
        (np.zeros(16), "shape"),
    ],
)
def test_bad_inputs_raise_clear_errors(paper, tau, message):
    sim = Simulator(paper)
    with pytest.raises(ValueError, match=message):
        sim.step(tau)


def test_reset_is_reproducible_and_current_moves_the_team():
    sim = Simulator(make("paper", current="strong", mismatch=0.1, seed=3))
    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, (20, 2, 8)) * sim.tau_max
    runs = []
    for _ in range(2):
        sim.reset(seed=3)
        for uk in u:
            sim.step(uk)
        runs.append(sim.flat_state.copy())
    assert np.array_equal(runs[0], runs[1])
    calm = Simulator(make("paper", seed=3))
    for uk in u:
        calm.step(uk)
    assert np.linalg.norm(calm.state.x_O[:2] - sim.state.x_O[:2]) > 1e-3


def test_internal_wrench_cancels_on_the_object(paper):
    sim = Simulator(paper)
    squeeze = sim.internal_wrench(
        np.array([[0, 5, 0, 0, 0, 0, 0, 0], [0, -5, 0, 0, 0, 0, 0, 0]], float)
    )
    assert np.abs(sim.grasp_matrix_t() @ squeeze.ravel()).max() < 1e-9
    assert np.abs(squeeze).max() > 0.1  # pushing the two vehicles together squeezes the bar


def test_the_period_routine_halves_refused_parts_in_order_and_stops_where_one_fails():
    """``uvms_env.sim.period`` on a stand-in step (x advances by h; a part is accurate when
    h is at most what its environment resolves): accepted at once, refined in halves (each
    half in order), refused at 1/16 where it stopped; each environment of a batch as alone."""
    period, n = 0.12, 2
    resolves = np.array([period, period / 4, period / 32, period / 2])
    calls: list[tuple[int, float]] = []

    def evaluate(ids, x0, h):
        cols = np.arange(len(resolves)) if ids is None else np.asarray(ids)
        calls.extend((int(c), h) for c in cols)
        inaccurate = (h > resolves[cols] * (1 + 1e-12)).astype(float)
        return x0 + h, np.tile(inaccurate, (12 * n, 1)), np.zeros((6 * n, len(cols)))

    control = PeriodControl(n)
    x0 = np.zeros((20 * n + 12, len(resolves)))
    x_end, ok, refined = control.integrate(evaluate, x0, period, len(resolves))
    assert ok.tolist() == [True, True, False, True] and refined == 3
    everyone = x_end.copy()
    np.testing.assert_allclose(x_end[:, [0, 1, 3]], period, rtol=1e-12)  # all of it, in parts
    assert not x_end[:, 2].any()  # stopped at its first 1/16, which started at x0
    parts = [h / period for env, h in calls if env == 1]
    assert parts == [1, 1 / 2, 1 / 4, 1 / 4, 1 / 2, 1 / 4, 1 / 4]
    assert [h / period for env, h in calls if env == 2] == [1, 1 / 2, 1 / 4, 1 / 8, 1 / 16]
    assert control.verdict(ok, x_end).tolist() == [OK, OK, INACCURATE, OK]
    x_end[20, 3] = 1.5 * SPEED_LIMITS["linear"]  # vehicle 0's surge, past the envelope
    assert control.verdict(ok, x_end).tolist() == [OK, OK, INACCURATE, ENVELOPE]
    for env in range(len(resolves)):  # K = 1: the same routine on one environment
        alone = resolves[[env]]

        def evaluate_alone(ids, x, h, alone=alone):
            inaccurate = float(h > alone[0] * (1 + 1e-12))
            return x + h, np.full((12 * n, 1), inaccurate), np.zeros((6 * n, 1))

        x_one, ok_one, _ = control.integrate(evaluate_alone, x0[:, [env]], period, 1)
        assert ok_one[0] == ok[env]
        assert np.array_equal(x_one[:, 0], everyone[:, env])
