"""The CUDA backend is the CPU backend: its kernel source, compiled for the host
(``device="cpu"``), and on a GPU when there is one, steps the same environments to
rounding in float64 (the period step with its in-kernel error control, observations,
rewards, constraint values, metrics, automatic resets, the priors), with torch tensors in
and out. The GPU tests skip without CuPy and a CUDA device."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.scenarios import make
from uvms_env.vector import VectorEnv
from uvms_env.vector.simulator import BatchedSimulator

torch = pytest.importorskip("torch")

TOL = 1e-9
ARRAY_INFOS = ("constraint_values", "cost", "success", "final_observation")


def _gpu() -> bool:
    try:
        import cupy

        return cupy.cuda.runtime.getDeviceCount() > 0
    except Exception:  # no CuPy, no driver or no GPU
        return False


def _host(x) -> np.ndarray:
    """A host copy of a numpy array, a torch tensor or a device array (CuPy's ``get``)."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return x.get() if hasattr(x, "get") else np.asarray(x)


def _agree(what: str, reference, candidate) -> None:
    a, b = np.asarray(reference, float), _host(candidate).astype(float)
    assert a.shape == b.shape, what
    assert np.allclose(a, b, rtol=0.0, atol=TOL), f"{what}: {np.abs(a - b).max():.3g}"


def test_kernel_source_on_the_host_steps_as_the_cpu_backend_with_its_error_control(emulated_xp):
    """The GPU's period kernel (error control inside, one thread per environment) against
    the CPU backend (lanes, error control on the host), saturating inputs that make both
    refine some periods."""
    geometries = [make("short", seed=i) for i in range(3)]
    k = 7
    cpu = BatchedSimulator(geometries[0], k, threads=2)
    emulated = BatchedSimulator(geometries[0], k, backend="cuda", device="cpu", threads=2)
    for sim in (cpu, emulated):
        for i in range(k):
            sim.set_scenario([i], geometries[i % 3])
        sim.reset(np.arange(k), list(range(100, 100 + k)))
    rng = np.random.default_rng(0)
    for t in range(100):
        shape = (k, 2, 8)
        u = rng.choice([-1.0, 1.0], shape) if t % 3 == 0 else rng.uniform(-1.2, 1.2, shape)
        current = np.c_[rng.uniform(-0.1, 0.1, (k, 2)), np.zeros(k)]
        code = cpu.step(u * cpu.tau_max, current)
        assert np.array_equal(code, _host(emulated.step(u * cpu.tau_max, current))), t
    assert emulated.refinements == cpu.refinements > 0  # the in-kernel control was used
    _agree("state after 100 periods", cpu.state(), emulated.state())


def _compare(
    scenario: str,
    k: int,
    steps: int,
    seed: int,
    restart_at: dict[int, list[int]] | None = None,
    **overrides,
) -> dict[str, int]:
    """Step the CPU backend and the emulated CUDA backend with the same random actions
    (torch tensors into the CUDA one); assert they agree. ``restart_at``: before step t,
    restart these environments (so that episodes end at different steps afterwards).
    Returns the episode ends seen."""
    cpu = VectorEnv(scenario, k, threads=2, **overrides)
    cuda = VectorEnv(scenario, k, backend="cuda", device="cpu", threads=2, **overrides)
    obs, _ = cpu.reset(seed=seed)
    obs_cuda, _ = cuda.reset(seed=seed)
    assert isinstance(obs_cuda, torch.Tensor) and obs_cuda.dtype == torch.float32
    _agree("reset observations", obs, obs_cuda)
    rng = np.random.default_rng(seed)
    ends: dict[str, int] = {}
    for t in range(steps):
        if restart_at and t in restart_at:
            ids = restart_at[t]
            _agree(f"restart, step {t}", cpu.restart(ids), cuda.restart(ids))
        act = rng.uniform(-1.0, 1.0, (k, cpu.n, 8))
        ref = cpu.step(act)
        out = cuda.step(torch.from_numpy(act))
        for name, a, b in zip(
            ("obs", "reward", "terminated", "truncated"), ref[:4], out[:4], strict=True
        ):
            assert isinstance(b, torch.Tensor), name
            _agree(f"{name}, step {t}", a, b)
        for key in ARRAY_INFOS:
            _agree(f"{key}, step {t}", ref[4][key], out[4][key])
        for name, value in ref[4]["reward_terms"].items():
            term = np.broadcast_to(value, (k,))
            _agree(f"reward term {name}, step {t}", term, out[4]["reward_terms"][name])
        assert list(ref[4]["episode_end"]) == list(out[4]["episode_end"]), t
        assert list(ref[4]["diverged_reason"]) == list(out[4]["diverged_reason"]), t
        for i, (m_ref, m_out) in enumerate(zip(ref[4]["metrics"], out[4]["metrics"], strict=True)):
            assert (m_ref is None) == (m_out is None), (t, i)
            if m_ref is not None:
                assert m_ref.keys() == m_out.keys()
                for key, value in m_ref.items():
                    if isinstance(value, float | int | list) and not isinstance(value, bool):
                        assert np.allclose(value, m_out[key], rtol=0, atol=TOL), (key, t, i)
                    else:  # flags, names, absent values (None)
                        assert value == m_out[key], (key, t, i)
                end = ref[4]["episode_end"][i]
                ends[end] = ends.get(end, 0) + 1
        if ref[4]["final_state"] is not None:
            _agree(f"final state, step {t}", ref[4]["final_state"], out[4]["final_state"])
    _agree("state", cpu.state(), cuda.state())
    return ends


def test_emulated_cuda_backend_equals_cpu_through_max_cycles_and_auto_resets(emulated_xp):
    # environments 1 and 3 restarted at step 10: their episodes end 10 steps after the
    # others' (resets of some environments, not all, inside the step)
    ends = _compare("short", 5, 70, seed=3, max_cycles=30, restart_at={10: [1, 3]})
    assert ends == {"max_cycles": 10}


def test_emulated_cuda_backend_equals_cpu_with_priors_pool_noise_and_current(emulated_xp):
    """Residual actions with the joint hold and features (a_ss and features by kernels on
    this backend, host calls on the CPU one), geometries from a pool (environment 2 on its
    own cycle), sensor noise and current drawn from each environment's own generator."""
    overrides = {
        "geometry_pool": 6,
        "action_mode": "residual",
        "hold_stiffness": 0.5,
        "hold_damping": 0.2,
        "observation_mode": "features",
        "sensor_noise": 1.0,
        "current": "strong",
        "max_cycles": 25,
    }
    ends = _compare("random", 4, 60, seed=3, restart_at={5: [2]}, **overrides)
    assert sum(ends.values()) >= 8


def test_emulated_cuda_backend_ends_episodes_by_constraint_as_the_cpu_backend(emulated_xp):
    ends = _compare("paper", 3, 40, seed=0, constraint_mode="terminate")
    assert ends.get("constraint", 0) >= 1


def test_cuda_backend_names_bad_devices_and_actions(emulated_xp):
    with pytest.raises(ValueError, match="device must be a GPU index"):
        VectorEnv("short", 2, backend="cuda", device="gpu0")
    with pytest.raises(ValueError, match="backend must be one of"):
        VectorEnv("short", 2, backend="tpu")
    venv = VectorEnv("short", 2, backend="cuda", device="cpu", max_cycles=5)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 2, 8\)"):
        venv.step(torch.zeros(2, 8))
    bad = torch.zeros(2, 2, 8, dtype=torch.float64)
    bad[1, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="environment 1, agent 'uvms_0'"):
        venv.step(bad)


@pytest.mark.skipif(not _gpu(), reason="needs CuPy and a CUDA GPU")
def test_gpu_float64_equals_cpu_over_100_periods_with_auto_resets():
    k = 64
    cpu = VectorEnv("paper", k, max_cycles=40)
    gpu = VectorEnv("paper", k, backend="cuda", device=0, max_cycles=40)
    obs, _ = cpu.reset(seed=0)
    obs_gpu, _ = gpu.reset(seed=0)
    assert obs_gpu.is_cuda
    _agree("reset", obs, obs_gpu)
    rng = np.random.default_rng(0)
    for t in range(100):
        act = rng.uniform(-1.0, 1.0, (k, 2, 8))
        ref = cpu.step(act)
        out = gpu.step(torch.as_tensor(act, device="cuda"))
        for name, a, b in zip(
            ("obs", "reward", "terminated", "truncated"), ref[:4], out[:4], strict=True
        ):
            assert b.is_cuda, name
            _agree(f"{name}, step {t}", a, b)
        assert list(ref[4]["episode_end"]) == list(out[4]["episode_end"]), t
    _agree("state", cpu.state(), gpu.state())


def test_the_kernel_refuses_outputs_it_would_write_out_of_place(emulated_xp):
    """The kernels write each output as a C-contiguous (nnz, K) block: a transposed view
    of the right shape is refused, not written past."""
    import casadi as cs

    from uvms_env.vector.kernels_cuda import cuda_function

    x = cs.SX.sym("x", 2)
    kernel = cuda_function(cs.Function("uvms_twice", [x], [2 * x]), "float64", "cpu")
    xp = kernel.xp
    inputs = xp.asarray(np.arange(10.0).reshape(2, 5))
    assert np.array_equal(_host(kernel([inputs])[0]), 2 * np.arange(10.0).reshape(2, 5))
    with pytest.raises(ValueError, match="output 0 must be a C-contiguous float64"):
        kernel([inputs], out=[xp.zeros((5, 2)).T])
