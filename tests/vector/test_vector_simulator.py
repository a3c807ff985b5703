"""The batched truth simulator is the single one, K times: same compiled period, same error
control, same envelope; float64 agrees to rounding, float32 within a measured bound."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.sim.period import ENVELOPE, OK, SPEED_LIMITS
from uvms_env.vector.batched_simulator import BatchedSimulator

K = 13  # not a multiple of any lane count: the padding is exercised


@pytest.fixture(scope="module")
def geometries():
    return [make("short", seed=i) for i in range(3)]


def _pair(geometries, **kwargs):
    bsim = BatchedSimulator(geometries[0], K, **kwargs)
    sims = []
    for k in range(K):
        s = geometries[k % len(geometries)]
        bsim.set_scenario([k], s)
        sims.append(Simulator(s))
    seeds = list(range(100, 100 + K))
    bsim.reset(np.arange(K), seeds)
    for sim, seed in zip(sims, seeds, strict=True):
        sim.reset(seed=seed)
    return bsim, sims


def _inputs(rng, t: int, tau_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = (K, 2, 8)
    u = rng.choice([-1.0, 1.0], shape) if t % 3 == 0 else rng.uniform(-1.2, 1.2, shape)
    current = np.c_[rng.uniform(-0.1, 0.1, (K, 2)), np.zeros(K)]
    return u * tau_max, current


def _step_singles(sims, tau, current) -> np.ndarray:
    refused = np.zeros(len(sims), bool)
    for k, sim in enumerate(sims):
        try:
            sim.step(tau[k], current[k])
        except FloatingPointError:
            refused[k] = True
    return refused


def test_float64_batch_equals_single_simulators_step_for_step(geometries):
    bsim, sims = _pair(geometries, threads=2)
    rng = np.random.default_rng(0)
    for t in range(60):
        tau, current = _inputs(rng, t, bsim.tau_max)
        code = bsim.step(tau, current)
        refused = _step_singles(sims, tau, current)
        assert np.array_equal(code != OK, refused), t
        single = np.stack([sim.flat_state for sim in sims])
        assert np.abs(bsim.state() - single).max() < 1e-10, t
    assert bsim.refinements == sum(sim.refinements for sim in sims) > 0  # control exercised


@pytest.mark.slow  # ~20 s building the scalar library alone; CI's budget
def test_scalar_build_equals_the_simd_build(geometries):
    simd, _ = _pair(geometries)
    scalar, _ = _pair(geometries, lanes=1)
    rng = np.random.default_rng(1)
    for t in range(20):
        tau, current = _inputs(rng, t, simd.tau_max)
        simd.step(tau, current)
        scalar.step(tau, current)
    assert np.abs(simd.state() - scalar.state()).max() < 1e-12


def test_float32_stays_within_its_documented_bound(geometries):
    """float32 is the fast mode: after 50 saturated periods its state stays within 1e-3
    of float64 (measured: ~1e-5; state magnitudes ~1)."""
    b64, _ = _pair(geometries)
    b32, _ = _pair(geometries, dtype="float32")
    rng = np.random.default_rng(2)
    for _ in range(50):
        tau = rng.uniform(-1, 1, (K, 2, 8)) * b64.tau_max
        b64.step(tau)
        b32.step(tau.astype(np.float32))
    assert np.abs(b32.state() - b64.state()).max() < 1e-3


def test_an_environment_beyond_the_envelope_is_refused_alone():
    s = make("paper", damping_scale=0.0)
    bsim = BatchedSimulator(s, 3)
    rng = np.random.default_rng(0)
    for _ in range(10):
        bsim.step(rng.uniform(-1, 1, (3, 2, 8)) * bsim.tau_max)
    x = bsim.state()
    n = 2
    zeta = x[1, 10 * n : 20 * n].reshape(n, 10)
    scale = 1.5 * SPEED_LIMITS["joint"] / np.abs(zeta[:, 6:]).max()
    x[1, 10 * n : 20 * n] *= scale  # the grasp velocity constraints are linear in these
    x[1, 20 * n + 6 :] *= scale
    bsim.set_state(x)
    code = bsim.step(np.zeros((3, 2, 8)))
    assert code.tolist() == [OK, ENVELOPE, OK]
    after = bsim.state()
    assert np.array_equal(after[1], x[1])  # refused: the last valid state is kept
    assert not np.array_equal(after[0], x[0])


def test_bad_input_raises_naming_the_problem(geometries):
    bsim = BatchedSimulator(geometries[0], 4)
    with pytest.raises(ValueError, match=r"tau must have shape \(4, 2, 8\)"):
        bsim.step(np.zeros((3, 2, 8)))
    tau = np.zeros((4, 2, 8))
    tau[2, 1, 3] = np.nan
    with pytest.raises(ValueError, match="environment 2"):
        bsim.step(tau)
    with pytest.raises(ValueError, match="share the team size"):
        bsim.set_scenario([0], make("random", n_agents=3, seed=0))
    with pytest.raises(ValueError, match="backend"):
        BatchedSimulator(geometries[0], 4, backend="tpu")
    with pytest.raises(ValueError, match="num_envs"):
        BatchedSimulator(geometries[0], 0)


def _cuda_available() -> bool:
    try:
        import cupy

        return cupy.cuda.runtime.getDeviceCount() > 0
    except Exception:  # no CuPy, no driver or no GPU: the test is skipped
        return False


@pytest.mark.skipif(not _cuda_available(), reason="needs CuPy and a CUDA GPU")
def test_cuda_float64_equals_cpu_float64(geometries):
    cpu, _ = _pair(geometries)
    gpu = BatchedSimulator(geometries[0], K, backend="cuda")
    for k in range(K):
        gpu.set_scenario([k], geometries[k % len(geometries)])
    gpu.reset(np.arange(K), list(range(100, 100 + K)))
    rng = np.random.default_rng(3)
    for t in range(100):
        tau, current = _inputs(rng, t, cpu.tau_max)
        code_cpu = cpu.step(tau, current)
        code_gpu = gpu.step(gpu.xp.asarray(tau), gpu.xp.asarray(current))
        assert np.array_equal(code_cpu, code_gpu.get())
    assert np.abs(cpu.state() - gpu.state().get()).max() < 1e-9
