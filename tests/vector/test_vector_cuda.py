"""The CUDA backend is the CPU backend: its kernel source, compiled for the host
(``device="cpu"``), and on a GPU when there is one, steps the same environments to
rounding in float64 (the period step with its in-kernel error control, observations,
rewards, constraint values, metrics, automatic resets, the priors), with torch tensors in
and out. The GPU tests skip without CuPy and a CUDA device."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from uvms_env.dynamics import NQ
from uvms_env.robot.observation import OBSERVATION_STRUCTURE
from uvms_env.scenarios import Scenario, make, replace
from uvms_env.sim.period import ENVELOPE, INACCURATE, OK, SPEED_LIMITS
from uvms_env.vector import VectorEnv
from uvms_env.vector.batched_simulator import BatchedSimulator

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
    the CPU backend (lanes, ``uvms_env.sim.period``'s routine on the host), saturating
    inputs that make both refine some periods; then a period that one environment cannot
    integrate (off the grasp manifold: refused at 1/16) and one that ends beyond the
    envelope, refused alike and kept."""
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
    x, n = cpu.state(), cpu.n
    x[2, 0] += 1e-3  # vehicle 0 of environment 2 moved off its grasp
    # environment 4 undamped, its joints beyond the envelope (the grasps' velocity
    # constraints are linear: scaled velocities still satisfy them)
    scale = 1.5 * SPEED_LIMITS["joint"] / np.abs(x[4, NQ * n : 2 * NQ * n]).max()
    x[4, NQ * n : 2 * NQ * n] *= scale
    x[4, 2 * NQ * n + 6 :] *= scale
    for sim in (cpu, emulated):
        sim.set_scenario([4], make("short", seed=1, damping_scale=0.0))
        sim.reset([4], [104])
        sim.set_state(x)
    refinements = cpu.refinements
    code = cpu.step(np.zeros((k, 2, 8)))
    assert code.tolist() == [OK, OK, INACCURATE, OK, ENVELOPE, OK, OK]
    assert np.array_equal(code, _host(emulated.step(np.zeros((k, 2, 8)))))
    assert emulated.refinements == cpu.refinements > refinements
    _agree("state after the refusals", cpu.state(), emulated.state())
    assert np.array_equal(cpu.state()[[2, 4]], x[[2, 4]])  # refused: kept


def _compare(
    scenario: str | Scenario,
    k: int,
    steps: int,
    seed: int,
    before: dict[int, Callable[[VectorEnv], Any]] | None = None,
    **overrides,
) -> tuple[dict[str, int], tuple]:
    """Step the CPU backend and the emulated CUDA backend with the same random actions
    (torch tensors into the CUDA one); assert they agree. ``before``: before step t, call
    ``before[t]`` on each (a restart, a reset, a perturbation) and compare what it returns.
    Returns the episode ends seen and the CPU backend's last step."""
    cpu = VectorEnv(scenario, k, threads=2, **overrides)
    cuda = VectorEnv(scenario, k, backend="cuda", device="cpu", threads=2, **overrides)
    obs, _ = cpu.reset(seed=seed)
    obs_cuda, _ = cuda.reset(seed=seed)
    assert isinstance(obs_cuda, torch.Tensor) and obs_cuda.dtype == torch.float32
    _agree("reset observations", obs, obs_cuda)
    rng = np.random.default_rng(seed)
    ends: dict[str, int] = {}
    for t in range(steps):
        if before and t in before:
            a, b = before[t](cpu), before[t](cuda)
            if a is not None:
                _agree(f"before step {t}", a, b)
        act = rng.uniform(-1.0, 1.0, (k, cpu.n, cpu.single_action_space.shape[0]))
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
                        close = np.allclose(value, m_out[key], rtol=0, atol=TOL, equal_nan=True)
                        assert close, (key, t, i)
                    else:  # flags, names, absent values (None)
                        assert value == m_out[key], (key, t, i)
                end = ref[4]["episode_end"][i]
                ends[end] = ends.get(end, 0) + 1
        if ref[4]["final_state"] is not None:
            _agree(f"final state, step {t}", ref[4]["final_state"], out[4]["final_state"])
    _agree("state", cpu.state(), cuda.state())
    return ends, ref


def test_emulated_cuda_backend_equals_cpu_through_max_cycles_and_auto_resets(emulated_xp):
    # environments 1 and 3 restarted at step 10: their episodes end 10 steps after the
    # others' (resets of some environments, not all, inside the step)
    restart = {10: lambda venv: venv.restart([1, 3])}
    ends, _ = _compare("short", 5, 70, seed=3, before=restart, max_cycles=30)
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
    before = {
        5: lambda venv: venv.restart([2]),
        55: lambda venv: venv.reset()[0],  # every environment on to its next pool geometry
    }
    ends, _ = _compare("random", 4, 60, seed=3, before=before, **overrides)
    assert sum(ends.values()) >= 8


def test_emulated_cuda_backend_equals_cpu_with_the_acoustic_channel(emulated_xp):
    """The channel's array code as CuPy runs it: the same deliveries, losses and inboxes
    on the device as on the host, through automatic resets."""
    comm = {"preset": "micromodem_fsk", "loss_probability": 0.3, "bit_rate_bps": 400.0,
            "modem_latency_periods": 2}  # fmt: skip
    ends, ref = _compare("random", 3, 40, seed=2, comm=comm, n_agents=3, max_cycles=15)
    assert ends == {"max_cycles": 6}
    assert ref[0][..., -1].any()  # messages arrived


def test_emulated_cuda_backend_ends_episodes_by_constraint_as_the_cpu_backend(emulated_xp):
    ends, _ = _compare("paper", 3, 40, seed=0, constraint_mode="terminate")
    assert ends.get("constraint", 0) >= 1


def _overspeed(venv: VectorEnv, env: int) -> None:
    """Environment ``env``'s first vehicle surging far beyond the physical envelope."""
    x = _host(venv.sim.state())
    x[env, NQ * venv.n] = 50.0
    venv.sim.set_state(x)


def test_emulated_cuda_backend_sequences_waypoints_and_ends_diverged_as_the_cpu_backend(
    emulated_xp,
):
    """Two waypoints at the start, then the paper's goal (three in all: the kernels'
    default room): the team passes one at the reset and one in the first step, each
    robot's sequencer both in its first two measurements; environment 1 then diverges
    (refused steps) and restarts."""
    paper = make("paper")
    start = np.asarray(paper.object_start)[None]
    goal = paper.waypoints[-1:]
    scenario = replace(paper, waypoints=np.vstack([start, start, goal]))
    before = {4: lambda venv: _overspeed(venv, 1)}
    ends, (obs, *_) = _compare(scenario, 3, 8, seed=0, before=before)
    assert ends == {"diverged": 1}
    # every robot aims at the first waypoint past the start
    assert np.allclose(obs[:, :, OBSERVATION_STRUCTURE["waypoint"]], goal[0])


def test_emulated_cuda_backend_ends_episodes_by_success_as_the_cpu_backend(emulated_xp):
    paper = make("paper")
    start = np.asarray(paper.object_start)[None]
    ends, _ = _compare(replace(paper, waypoints=np.vstack([start, start])), 2, 3, seed=0)
    assert ends == {"success": 6}


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


@pytest.mark.parametrize("emulated_xp", ["strict"], indirect=True)
def test_the_step_reads_the_device_a_fixed_number_of_times_whatever_k(emulated_xp):
    """Device-to-host reads (each a synchronization on a GPU, boolean masks included) per
    step: a few flags, the same for 2 environments as for 5, whether episodes end or not
    (the ended ones come over together)."""
    from strict_xp import host_reads

    def reads(k: int) -> list[int]:
        venv = VectorEnv("short", k, backend="cuda", device="cpu", max_cycles=2)
        venv.reset(seed=0)
        counts = []
        for _ in range(3):  # every episode ends in the second step
            host_reads.clear()
            venv.step(torch.zeros(k, 2, 8))
            counts.append(host_reads.total())
        return counts

    two = reads(2)
    assert two == reads(5)
    assert two[0] == two[2] < two[1] <= 30


def test_the_cuda_sources_mark_every_function_and_table_as_device_code():
    """What the host emulation cannot check (it defines ``__device__`` away): every
    function and constant table of the kernels the backend compiles is device code, so
    that NVRTC or nvcc finds no host function called from the kernel."""
    import re

    from uvms_env.vector.kernels import cuda_source, generated_source
    from uvms_env.vector.kernels_check import backend_kernels

    # a definition at the top level not marked __device__/__global__, or a constant table
    host_code = re.compile(
        r"^(?!__device__|__global__|extern|#|\}|\{|/\*|\s)[^;]*\([^;]*\)\s*\{"
        r"|^(static |const )+casadi_(int|real) "
    )
    for kernel in backend_kernels(2):
        fn = kernel.fn
        unmarked = [line for line in generated_source(fn).split("\n") if host_code.match(line)]
        assert unmarked, fn.name()  # the pattern finds the generated functions ...
        source, _ = cuda_source(fn, "double", kernel.refine)
        left = [line[:80] for line in source.split("\n") if host_code.match(line)]
        assert not left, (fn.name(), left[:3])  # ... and none is left unmarked
