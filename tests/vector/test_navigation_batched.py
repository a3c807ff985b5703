"""The navigator's twist with the scene as inputs (uvms_env.navigation.parametric): equal to
every scene's own function inside and outside the free space, padding rows neutral, and
branch-free, so that environments of different geometries share one batched build."""

from __future__ import annotations

import re
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from uvms_env.navigation import (
    Cylinder,
    WaypointNavigator,
    field_parameters,
    parametric_twist_function,
    sample_free_points,
    twist_parameters,
)
from uvms_env.scenarios import make
from uvms_env.vector.kernels import (
    ADDRESS_LISTS,
    BatchedFunction,
    cuda_source,
    generated_source,
)

K = 13  # environments per batched call, not a multiple of any lane count
TOL = 1e-12


@pytest.fixture(scope="module")
def fn() -> ca.Function:
    return parametric_twist_function()


@pytest.fixture(scope="module")
def scenes():
    """Paper, short and random scenes: cylinders only, spheres only, mixed, none; 2..6
    agents (other team radii)."""
    seeds = (0, 1, 3, 4, 10, 19)  # 1: three spheres, 10: three cylinders, 19: both
    random = [make("random", n_agents=2 + s % 5, seed=s) for s in seeds]
    return [make("paper"), make("short", seed=2), *random]


def _navigator(scene, j: int) -> WaypointNavigator:
    """Every parameter varied from scene to scene, not only the geometry."""
    return WaypointNavigator(
        scene.waypoints,
        scene.workspace,
        scene.obstacles,
        scene.team_radius,
        k=(6.0, 9.0, 13.5, 20.0)[j % 4],
        gain=0.3 + 0.1 * (j % 3),
        max_speed=0.2 + 0.05 * (j % 2),
        att_gain=0.15 + 0.05 * (j % 3),
        max_att_rate=0.04 + 0.01 * (j % 2),
    )


def _points(scene, navigator: WaypointNavigator, index: int, rng) -> np.ndarray:
    """Poses (M, 6): uniform over the workspace's bounding cube and beyond it, free
    samples, the goal itself, around and at the centre of every obstacle."""
    field = navigator.fields[index]
    c, r = np.asarray(scene.workspace.center), scene.workspace.radius
    pts = [c + rng.uniform(-1.2 * r, 1.2 * r, (200, 3)), sample_free_points(field, 50, rng)]
    pts.append(field.goal[None])
    for o in scene.obstacles:
        centre = np.array([o.x, o.y, c[2]]) if isinstance(o, Cylinder) else np.array(o.center)
        pts += [centre[None], centre + rng.normal(0.0, o.radius + scene.team_radius, (30, 3))]
    p = np.concatenate(pts)
    return np.c_[p, rng.uniform(-7.0, 7.0, (p.shape[0], 3))]


def test_equals_each_scenes_own_function_inside_and_outside_the_free_space(fn, scenes):
    rng = np.random.default_rng(0)
    worst = 0.0
    for j, scene in enumerate(scenes):
        nav = _navigator(scene, j)
        for i in range(len(nav.sequencer)):
            x = _points(scene, nav, i, rng)
            free = nav.fields[i].clearance_batch(x[:, :3]) > 0.0
            assert free.any() and (~free).any()  # both the field and the recovery branch
            ref = np.asarray(nav.casadi_function(i).map(x.shape[0])(x.T))
            got = np.asarray(fn.map(x.shape[0])(x.T, *twist_parameters(nav, i)))
            assert np.all(np.isfinite(got))
            worst = max(worst, float(np.abs(got - ref).max()))
    assert worst < TOL  # measured: 0 (the same operations in the same order)


def test_padding_rows_change_nothing():
    scene = make("random", seed=19)  # one cylinder, three spheres
    nav = _navigator(scene, 1)
    x = _points(scene, nav, 0, np.random.default_rng(1))
    goal, workspace, cylinders, spheres, gains = twist_parameters(nav, 0)
    tight = parametric_twist_function(1, 3)
    ref = np.asarray(tight.map(x.shape[0])(x.T, goal, workspace, cylinders[:1], spheres[:3], gains))
    junk = np.random.default_rng(2).uniform(-50.0, 50.0, (2, 5, 5))
    cylinders[1:, :3], spheres[3:, :4] = junk[0, 1:, :3], junk[1, 3:, :4]
    assert cylinders[1:, 3].tolist() == [0.0] * 4 and spheres[3:, 4].tolist() == [0.0] * 2
    padded = parametric_twist_function()
    got = np.asarray(padded.map(x.shape[0])(x.T, goal, workspace, cylinders, spheres, gains))
    assert np.array_equal(got, ref)


def test_more_obstacles_than_slots_raise():
    field = _navigator(make("paper"), 0).fields[0]
    with pytest.raises(ValueError, match="3 cylinders and 0 spheres; the function has slots"):
        field_parameters(field, n_cyl=2)


def test_generated_code_is_branch_free(fn):
    """No ternary but the generated argument checks (``arg[i] ? arg[i][j] : 0``): what
    SIMD lanes cannot take is a select on a value."""
    src = generated_source(fn)
    body = src[src.index("static int casadi_f0(") :]
    body = body[: body.index("CASADI_SYMBOL_EXPORT")]
    body = re.sub(r"arg\[\d+\]\? arg\[\d+\]\[\d+\] : 0", "", body)
    assert "?" not in body and "if_else" not in body


def _batch(scenes, rng):
    """K environments, each a different scene (navigator parameters too), waypoint and
    pose: the (nnz_i, K) inputs and each one's own function's twist (6, K)."""
    columns: list[list[np.ndarray]] = [[] for _ in range(6)]
    ref, free = [], []
    for e in range(K):
        scene = scenes[e % len(scenes)]
        nav = _navigator(scene, e)
        i = e % len(nav.sequencer)
        x = _points(scene, nav, i, rng)
        inside = nav.fields[i].clearance_batch(x[:, :3]) > 0.0
        pick = rng.choice(x[inside == (e % 2 == 0)])  # free and not free in turn
        ref.append(np.asarray(nav.casadi_function(i)(pick)).ravel())
        free.append(nav.fields[i].clearance_batch(pick[None, :3])[0] > 0.0)
        for col, value in zip(columns, [pick, *twist_parameters(nav, i)], strict=True):
            col.append(np.asarray(value).ravel(order="F"))
    inputs = [np.ascontiguousarray(np.stack(col, axis=1)) for col in columns]
    return inputs, np.stack(ref, axis=1), np.array(free)


@pytest.mark.parametrize("lanes", [None, 1])
def test_one_batched_call_evaluates_different_geometries(fn, scenes, lanes):
    inputs, ref, free = _batch(scenes, np.random.default_rng(3))
    assert free.any() and (~free).any()
    bf = BatchedFunction(fn, "float64", lanes)
    k = bf.padded(K)
    padded = [np.ascontiguousarray(np.pad(a, ((0, 0), (0, k - K)), mode="edge")) for a in inputs]
    out = bf(padded)[0][:, :K]
    assert np.abs(out - ref).max() < TOL  # measured: 0


def test_a_call_reads_the_arrays_it_is_given_now(fn, scenes):
    """The batched call keeps the addresses of argument lists it saw (by the arrays'
    identities): the same arrays with new contents, and new arrays, each give their own
    results, also past the number of lists it keeps."""
    bf = BatchedFunction(fn, "float64", lanes=1)
    inputs, ref, _ = _batch(scenes, np.random.default_rng(3))
    other, ref_other, _ = _batch(scenes, np.random.default_rng(4))
    out = [np.zeros((6, K))]
    assert np.abs(bf(inputs, out=out)[0] - ref).max() < TOL
    for mine, theirs in zip(inputs, other, strict=True):
        mine[...] = theirs  # in place: the same arrays, the list seen before
    assert np.abs(bf(inputs, out=out)[0] - ref_other).max() < TOL
    for _ in range(ADDRESS_LISTS + 2):
        fresh = [a.copy() for a in other]
        assert np.abs(bf(fresh)[0] - ref_other).max() < TOL
        del fresh  # freed: a later list may reuse its identities
    assert np.abs(bf(inputs, out=out)[0] - ref_other).max() < TOL


@pytest.mark.skipif(shutil.which("nvcc") is None, reason="needs nvcc")
def test_cuda_source_compiles(fn, tmp_path):
    source, sig = cuda_source(fn)
    assert sig.nnz_in == (6, 6, 4, 20, 25, 5) and sig.nnz_out == (6,)
    src = tmp_path / "nav.cu"
    src.write_text(source)
    cmd = ["nvcc", "-std=c++17", "-arch=sm_90", "-cubin", "-x", "cu", str(src)]
    subprocess.run([*cmd, "-o", str(tmp_path / "nav.cubin")], check=True, timeout=300)
