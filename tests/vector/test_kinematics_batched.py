"""The environment's per-step kinematics kernel (uvms_env.task.team_kernel) batched: its
generated code is branch-free, a fixed obstacle padding (and repeated object segments)
gives the per-scenario kernel's results bit for bit, and one batched call over
environments of different geometries and states equals each environment's own kernel."""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass

import casadi as ca
import numpy as np
import pytest

from uvms_env.dynamics import NU
from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT
from uvms_env.scenarios import Scenario, make
from uvms_env.sim import Simulator
from uvms_env.task.team_kernel import (
    CYLINDER_SLOTS,
    SPHERE_SLOTS,
    TeamKinematics,
    obstacle_inputs,
    segment_inputs,
    team_function,
)
from uvms_env.task.team_rows import TEAM_ROWS
from uvms_env.vector.kernels import BatchedFunction, cuda_source, generated_source

K = 13  # environments per batched call
N = 2  # robots: one team size per kernel
N_SEG = 24  # the ring's segments (random family); the bar's one is repeated
TOL = 1e-12


@dataclass
class Env:
    scene: Scenario
    segments: list
    kin: TeamKinematics  # the per-scenario kernel (the single environment's)
    state: tuple[np.ndarray, ...]  # action, q, zeta, q_meas, zeta_meas, x_O, sequencers, team


def _shared(noisy: bool = False) -> ca.Function:
    """The symbolic kernel of every two-robot geometry."""
    return team_function(
        N, N_SEG, CYLINDER_SLOTS, SPHERE_SLOTS, OBSERVATION_LAYOUT, FAR_OBSTACLE, noisy
    )


@pytest.fixture(scope="module")
def envs() -> list[Env]:
    """Random scenes (ring, 1..3 waypoints; cylinders only, spheres only, both) and short
    ones (bar, no obstacle), each after a few random simulator steps, with random
    requested actions (some beyond the saturation), measurements, sequencers (waypoint
    index and done flag; the team's with its tests' constants) and time fractions."""
    rng = np.random.default_rng(0)
    scenes = [make("random", n_agents=N, seed=i) for i in range(7)]
    scenes += [make("short", seed=i) for i in range(K - 7)]
    out = []
    for e, scene in enumerate(scenes):
        sim = Simulator(scene)
        for _ in range(2 + e % 3):
            sim.step(rng.uniform(-1.0, 1.0, (N, NU)) * sim.tau_max)
        st = sim.state
        kin = TeamKinematics(scene, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE)
        kin.time_fraction[0] = rng.uniform()
        sequencers = np.c_[rng.integers(len(scene.waypoints), size=N), rng.integers(2, size=N)]
        q, zeta = st.q.copy(), st.zeta.copy()
        tests = (rng.uniform(0.1, 1.0), scene.success_pos_tol, scene.success_att_tol)
        team = np.r_[rng.integers(len(scene.waypoints)), rng.integers(2), tests]
        state = (
            rng.uniform(-1.5, 1.5, (N, NU)),
            q,
            zeta,
            q + rng.normal(0.0, 0.01, q.shape),
            zeta + rng.normal(0.0, 0.01, zeta.shape),
            st.x_O.copy(),
            sequencers.astype(float),
            team.astype(float),
        )
        out.append(Env(scene, sim.object.segments, kin, state))
    return out


def _inputs(env: Env, padded: bool) -> list[np.ndarray]:
    """The kernel's 18 inputs in TeamKinematics' layout (C-contiguous transposes of
    CasADi's shapes): its own padding, or the shared one (5 + 5 obstacle slots, 24
    segments)."""
    kin = env.kin
    seg, cyl, sph = kin.segments, kin.cylinders, kin.spheres
    if padded:
        seg = segment_inputs(env.segments, N_SEG)
        cyl, sph = obstacle_inputs(env.scene, CYLINDER_SLOTS, SPHERE_SLOTS)
    fixed = [kin.grasp, kin.static, *env.state[6:8], kin.waypoints, kin.count, kin.goal]
    inputs = [*env.state[:6], *fixed, kin.time_fraction, seg, cyl, sph, kin.workspace]
    return [np.ascontiguousarray(x, dtype=float) for x in inputs]


def _symbolic(fn: ca.Function, inputs: list[np.ndarray]) -> np.ndarray:
    """Every output's nonzeros, evaluated by CasADi's virtual machine (no compiler)."""
    res = fn.call([ca.DM(x.T) if x.ndim == 2 else ca.DM(x) for x in inputs])
    return np.concatenate([np.asarray(r).ravel(order="F") for r in res])


def _compiled(env: Env) -> np.ndarray:
    """Every output's nonzeros from the single environment's compiled kernel."""
    env.kin(*[np.ascontiguousarray(x) for x in env.state])
    return np.concatenate([np.asarray(o).ravel() for o in env.kin._call.outputs])


def test_scenes_cover_every_kind_of_geometry(envs):
    kinds = {(int(e.kin.cylinders[:, 3].sum()), int(e.kin.spheres[:, 4].sum())) for e in envs}
    assert {(0, 0), (2, 0), (0, 3), (1, 2)} <= kinds
    assert {len(e.segments) for e in envs} == {1, N_SEG}


def test_generated_code_is_branch_free():
    """No ternary but the argument checks on pointers (``arg[i] ? arg[i][j] : 0``) and
    CasADi's helpers (their C99 bodies call fmin / fmax / fabs; ``is_dense`` is an int):
    what SIMD lanes cannot take is a select on a value."""
    src = generated_source(_shared())
    body = src[src.index("static int casadi_f") :]
    body = body[: body.index("CASADI_SYMBOL_EXPORT")]
    body = re.sub(r"arg\[\d+\] ?\? ?arg\[\d+\](\[\d+\])? : (0|casadi_zeros)", "", body)
    assert "?" not in body and "if_else" not in body


@pytest.mark.parametrize("noisy", [False, True])
def test_fixed_padding_equals_the_per_scenario_padding(envs, noisy):
    """Bit for bit in CasADi's virtual machine, padding rows of any finite geometry
    included (compiled, the two kernels may differ by FMA contraction: ~1e-14)."""
    shared = _shared(noisy)
    junk = np.random.default_rng(1)
    for env in envs:
        kin = env.kin
        own = team_function(
            N,
            len(env.segments),
            kin.cylinders.shape[0],
            kin.spheres.shape[0],
            OBSERVATION_LAYOUT,
            FAR_OBSTACLE,
            noisy,
        )
        ref = _symbolic(own, _inputs(env, padded=False))
        inputs = _inputs(env, padded=True)
        cyl, sph = inputs[-3], inputs[-2]
        assert cyl.shape == (CYLINDER_SLOTS, 4) and sph.shape == (SPHERE_SLOTS, 5)
        got = _symbolic(shared, inputs)
        assert np.array_equal(got, ref)
        # absent rows around the object (present stays 0) change nothing either
        centre = env.state[5][:3]
        for rows, dim in ((cyl, 2), (sph, 3)):
            absent = rows[:, dim + 1] == 0
            m = int(absent.sum())
            rows[absent, :dim] = centre[:dim] + junk.uniform(-3.0, 3.0, (m, dim))
            rows[absent, dim] = junk.uniform(0.1, 2.0, m)
        assert np.array_equal(_symbolic(shared, inputs), ref)
        if not env.scene.obstacles:
            assert np.isinf(ref[-TEAM_ROWS - 2 * N])  # the team's clearance: no obstacle at all


def test_one_batched_call_evaluates_different_geometries(envs):
    ref = np.stack([_compiled(env) for env in envs], axis=1)
    columns = [_inputs(env, padded=True) for env in envs]
    inputs = [
        np.ascontiguousarray(np.stack([c[i].ravel() for c in columns], axis=1))
        for i in range(len(columns[0]))
    ]
    bf = BatchedFunction(_shared(), "float64")  # the batched environment's own build
    width = bf.padded(K)  # whole bundles of lanes: the last geometry repeated
    inputs = [np.ascontiguousarray(np.pad(a, ((0, 0), (0, width - K)), "edge")) for a in inputs]
    got = np.concatenate(bf(inputs))[:, :K]
    assert got.shape == ref.shape
    assert np.isinf(ref).any() and np.array_equal(np.isinf(got), np.isinf(ref))
    finite = np.isfinite(ref)
    assert np.isfinite(got[finite]).all()
    assert np.array_equal(got[~finite], ref[~finite])
    assert np.abs(got[finite] - ref[finite]).max() < TOL  # measured: 1.1e-16 (FMA contraction)


def test_inputs_refuse_what_does_not_fit():
    with pytest.raises(ValueError, match="3 cylinders and 0 spheres; the kernel has slots"):
        obstacle_inputs(make("paper"), 2, 5)
    seg = [(np.zeros(3), np.ones(3))] * 2
    with pytest.raises(ValueError, match="2 segments do not fit 1 slots"):
        segment_inputs(seg, 1)
    assert segment_inputs(seg, 3).shape == (3, 6)


@pytest.mark.slow  # ~14 s of nvcc; CI's budget
@pytest.mark.skipif(shutil.which("nvcc") is None, reason="needs nvcc")
def test_cuda_source_compiles(tmp_path):
    source, sig = cuda_source(_shared())
    assert sig.nnz_in[-3:] == (4 * CYLINDER_SLOTS, 5 * SPHERE_SLOTS, 4)
    src = tmp_path / "kinematics.cu"
    src.write_text(source)
    cmd = ["nvcc", "-std=c++17", "-arch=sm_90", "-cubin", "-x", "cu", str(src)]
    subprocess.run([*cmd, "-o", str(tmp_path / "kinematics.cubin")], check=True, timeout=600)
