"""Tests of uvms_env.navigation: numerics, CasADi parity, paper path, local minima, input checks."""

from __future__ import annotations

import math
from functools import partial

import casadi as ca
import numpy as np
import pytest
from nav_points import (
    PointField,
    attitude_rate,
    desired_velocity_batch,
    grad_log_phi_batch,
    grad_phi_batch,
    log_phi_batch,
    phi_batch,
    twist,
)

from uvms_env.dynamics.spatial import euler_rate_matrix
from uvms_env.navigation import (
    Cylinder,
    NavigationField,
    Obstacle,
    Sphere,
    WaypointNavigator,
    WaypointSequencer,
    Workspace,
    choose_k,
    descend,
    sample_free_points,
    wrap_angle,
)

# ---------------------------------------------------------------- paper scenario
PAPER_WORKSPACE = Workspace((6.0, 0.5, 0.75), 14.0)
PAPER_OBSTACLES: list[Obstacle] = [
    Cylinder(4.0, -4.5, 0.6),
    Cylinder(9.0, -1.5, 0.6),
    Cylinder(9.0, 5.0, 0.6),
]
PAPER_START = np.array([-0.7, 0.0, 0.72])
PAPER_WAYPOINTS = np.array(
    [
        [6.0, -6.0, 0.85, 0.0, 0.0, 0.0],
        [7.5, 1.5, 0.78, 0.0, 0.0, 0.0],
        [12.0, 6.5, 0.65, 0.0, 0.0, 0.0],
    ]
)
PAPER_TEAM_RADIUS = 1.3
#: k for the paper scenario: choose_k gives 2-3 per waypoint field; 6 leaves a margin
#: against spurious minima while keeping ~0.4 m clearance (larger k hugs obstacles).
PAPER_K = 6.0

# A scene with both obstacle kinds, used by the numerical checks.
MIXED_OBSTACLES: list[Obstacle] = [
    *PAPER_OBSTACLES,
    Sphere((1.0, 3.0, 1.0), 0.5),
    Sphere((12.0, -2.0, -1.0), 0.8),
]


def _mixed_field(k: float) -> NavigationField:
    return NavigationField((7.5, 1.5, 0.78), PAPER_WORKSPACE, MIXED_OBSTACLES, 1.3, k=k)


def _naive_phi(field: NavigationField, p: np.ndarray) -> float:
    gamma = float(np.sum((p - field.goal) ** 2))
    return gamma / (gamma**field.k + _naive_beta(field, p)) ** (1.0 / field.k)


def _central_diff(fun, points: np.ndarray, h: float = 1e-6) -> np.ndarray:
    return np.stack(
        [(fun(points + h * e) - fun(points - h * e)) / (2.0 * h) for e in np.eye(3)], axis=1
    )


# ---------------------------------------------------------------- 1. log form, gradients
@pytest.mark.parametrize("k", [1.0, 2.0, 4.0, 6.0])
def test_log_form_matches_naive_formula(k: float) -> None:
    field = _mixed_field(k)
    pts = sample_free_points(field, 100, np.random.default_rng(1))
    naive = np.array([_naive_phi(field, p) for p in pts])
    assert np.all(np.isfinite(naive))
    np.testing.assert_allclose(phi_batch(field, pts), naive, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(log_phi_batch(field, pts), np.log(naive), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("k", [2.0, 6.0])
def test_gradients_match_finite_differences(k: float) -> None:
    field = _mixed_field(k)
    pts = sample_free_points(field, 100, np.random.default_rng(2), min_clearance=0.05)
    fd_log = _central_diff(partial(log_phi_batch, field), pts)
    np.testing.assert_allclose(grad_log_phi_batch(field, pts), fd_log, rtol=1e-5, atol=1e-7)
    fd_phi = _central_diff(partial(phi_batch, field), pts)
    np.testing.assert_allclose(grad_phi_batch(field, pts), fd_phi, rtol=1e-5, atol=1e-8)


def test_desired_velocity_direction_and_speed() -> None:
    field = _mixed_field(6.0)
    pts = sample_free_points(field, 200, np.random.default_rng(3))
    v = desired_velocity_batch(field, pts)
    g = grad_log_phi_batch(field, pts)
    cos = -np.sum(v * g, axis=1) / (np.linalg.norm(v, axis=1) * np.linalg.norm(g, axis=1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-9)
    dist = np.linalg.norm(pts - field.goal, axis=1)
    expected = np.minimum(field.max_speed, field.gain * dist)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), expected, rtol=1e-9)
    # near the goal the reference is -K_NF (p - p_d)
    p = field.goal + np.array([1e-3, -2e-3, 5e-4])
    v = PointField(field).desired_velocity(p)
    np.testing.assert_allclose(v, -field.gain * (p - field.goal), rtol=1e-3)


def test_casadi_function_matches_numpy() -> None:
    field = _mixed_field(6.0)
    fun = field.casadi_function()
    assert fun.name() == "nav_velocity"
    assert fun.size_in(0) == (3, 1) and fun.size_out(0) == (3, 1)
    rng = np.random.default_rng(4)
    free = sample_free_points(field, 200, rng)
    outside = np.array([[9.0, -1.2, 0.7], [30.0, 0.0, 0.0], [1.2, 3.1, 1.0]])
    pts = np.vstack([free, field.goal, field.goal + 1e-9, outside])
    v_ca = np.array(fun(pts.T)).T
    np.testing.assert_allclose(v_ca, desired_velocity_batch(field, pts), rtol=1e-12, atol=1e-14)
    # the MPC needs derivatives: finite Jacobian, -K_NF I at the goal
    p = ca.SX.sym("p", 3)
    jac = ca.Function("nav_jac", [p], [ca.jacobian(fun(p), p)])
    np.testing.assert_allclose(np.array(jac(field.goal)), -field.gain * np.eye(3), atol=1e-9)
    for q in free[:20]:
        assert np.all(np.isfinite(np.array(jac(q))))


def test_twist_casadi_matches_numpy() -> None:
    nav = WaypointNavigator(
        PAPER_WAYPOINTS, PAPER_WORKSPACE, PAPER_OBSTACLES, PAPER_TEAM_RADIUS, k=PAPER_K
    )
    rng = np.random.default_rng(5)
    for i in range(len(PAPER_WAYPOINTS)):
        fun = nav.casadi_function(i)
        for _ in range(20):
            pos = sample_free_points(nav.fields[i], 1, rng)[0]
            x = np.concatenate([pos, rng.uniform(-4.0, 4.0, 3)])
            np.testing.assert_allclose(
                np.array(fun(x)).ravel(), twist(nav, x, i), rtol=1e-12, atol=1e-14
            )


# ---------------------------------------------------------------- 2. large k, far points
@pytest.mark.parametrize("k", [40.0, 50.0, 200.0])
def test_no_overflow_for_large_k_and_far_points(k: float) -> None:
    ws = Workspace((0.0, 0.0, 0.0), 60.0)
    obstacles: list[Obstacle] = [Cylinder(10.0, 5.0, 1.0), Sphere((-15.0, 0.0, 3.0), 2.0)]
    field = NavigationField((0.0, 0.0, 0.0), ws, obstacles, 1.0, k=k)
    rng = np.random.default_rng(6)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    pts = dirs * rng.uniform(25.0, 45.0, size=(200, 1))  # gamma ~ 6e2 .. 2e3
    pts = pts[field.clearance_batch(pts) > 0.0]
    special = np.array([[0.0, 0.0, 0.0], [1e-12, 0.0, 0.0], [10.0, 7.0 + 1e-9, 0.0]])
    # underflow to 0 (e.g. exp(-huge) inside logaddexp) is harmless and allowed
    with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
        for q in (pts, special):
            log_phi = log_phi_batch(field, q)
            phi = phi_batch(field, q)
            g = grad_log_phi_batch(field, q)
            gp = grad_phi_batch(field, q)
            v = desired_velocity_batch(field, q)
            assert not np.any(np.isnan(log_phi))
            assert np.all((phi >= 0.0) & (phi <= 1.0))
            assert np.all(np.isfinite(g)) and np.all(np.isfinite(gp)) and np.all(np.isfinite(v))
    # far away phi is flat at 1 but the direction is the exact RK one:
    # -grad phi  ~  -(k beta grad gamma - gamma grad beta)   (beta is moderate here)
    assert np.all(phi_batch(field, pts) > 1.0 - 1e-12)
    v = desired_velocity_batch(field, pts)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), field.max_speed, rtol=1e-12)
    h = 1e-4
    for p, vp in zip(pts[:30], v[:30], strict=True):
        gamma = float(p @ p)
        beta = _naive_beta(field, p)
        grad_beta = np.array([(_naive_beta(field, p + h * e) - beta) / h for e in np.eye(3)])
        naive = -(k * beta * 2.0 * p - gamma * grad_beta)
        cos = float(vp @ naive) / (np.linalg.norm(vp) * np.linalg.norm(naive))
        assert cos > 1.0 - 1e-6
    # the goal itself
    field = PointField(field)
    assert field.log_phi(field.goal) == -math.inf
    assert field.phi(field.goal) == 0.0
    np.testing.assert_array_equal(field.grad_log_phi(field.goal), 0.0)
    np.testing.assert_array_equal(field.desired_velocity(field.goal), 0.0)


def _naive_beta(field: NavigationField, p: np.ndarray) -> float:
    c = np.asarray(field.workspace.center)
    beta = (field.workspace.radius - field.team_radius) ** 2 - float(np.sum((p - c) ** 2))
    for obs in field.obstacles:
        if isinstance(obs, Cylinder):
            d2 = (p[0] - obs.x) ** 2 + (p[1] - obs.y) ** 2
        else:
            d2 = float(np.sum((p - np.asarray(obs.center)) ** 2))
        beta *= d2 - (obs.radius + field.team_radius) ** 2
    return beta


def test_outside_free_space_conventions() -> None:
    field = PointField(_mixed_field(6.0))
    # inside the inflated cylinder at (9, -1.5): recovery pushes radially outwards
    p = np.array([9.5, -1.5, 0.7])
    assert field.clearance(p) < 0.0
    assert field.log_phi(p) == 0.0 and field.phi(p) == 1.0
    np.testing.assert_allclose(field.desired_velocity(p), [field.max_speed, 0.0, 0.0])
    np.testing.assert_allclose(field.grad_log_phi(p), [-1.0, 0.0, 0.0])
    np.testing.assert_array_equal(field.grad_phi(p), 0.0)
    # outside the workspace: back towards its centre
    q = np.array([6.0 + 13.0, 0.5, 0.75])
    assert field.clearance(q) < 0.0
    np.testing.assert_allclose(field.desired_velocity(q), [-field.max_speed, 0.0, 0.0])
    # clearance is a signed distance
    assert field.clearance([9.0 - 1.9 - 0.25, -1.5, 0.7]) == pytest.approx(0.25)
    assert field.clearance([9.0 - 1.9 + 0.25, -1.5, 0.7]) == pytest.approx(-0.25)


# ---------------------------------------------------------------- 3. paper path
def test_paper_scenario_reaches_all_waypoints_safely() -> None:
    nav = WaypointNavigator(
        PAPER_WAYPOINTS, PAPER_WORKSPACE, PAPER_OBSTACLES, PAPER_TEAM_RADIUS, k=PAPER_K
    )
    x = np.concatenate([PAPER_START, [0.1, -0.05, 0.3]])
    dt, t, t_max = 0.1, 0.0, 2000.0
    reached_at: list[float] = []
    min_clearance = math.inf
    index, done = 0, False
    obstacles = PointField(nav.fields[0])
    while t < t_max and not done:
        # a waypoint is passed within 0.3 m, one per step at most (the task's rule)
        if np.linalg.norm(x[:3] - PAPER_WAYPOINTS[index, :3]) < 0.3:
            reached_at.append(t)
            done = index == len(PAPER_WAYPOINTS) - 1
            index += not done
        x = x + dt * twist(nav, x, index)
        t += dt
        min_clearance = min(min_clearance, obstacles.clearance(x[:3]))
        assert min_clearance > 0.0, f"entered an inflated obstacle at t = {t:.1f} s"
    print(f"paper path: k = {PAPER_K}, waypoints at {reached_at} s, min clearance {min_clearance}")
    assert done
    assert len(reached_at) == 3
    assert reached_at == sorted(reached_at)
    assert np.linalg.norm(x[:3] - PAPER_WAYPOINTS[-1, :3]) < 0.3
    assert np.max(np.abs(wrap_angle(x[3:]))) < 0.05  # attitude term did its job too
    assert min_clearance > 0.2


# ---------------------------------------------------------------- 4. local minima
def _random_scene(
    rng: np.random.Generator, ws_radius: float = 8.0, team_radius: float = 1.0
) -> tuple[np.ndarray, Workspace, list[Obstacle]]:
    """2-5 cylinders/spheres (radius 0.3-1.0), inflated copies 0.5 m apart and off the wall."""
    margin = 0.5
    ws = Workspace((0.0, 0.0, 0.0), ws_radius)
    inner = ws_radius - team_radius
    while True:
        count = int(rng.integers(2, 6))
        obstacles: list[Obstacle] = []
        centres: list[np.ndarray] = []
        for _ in range(1000):
            if len(obstacles) == count:
                break
            r = float(rng.uniform(0.3, 1.0))
            is_cylinder = bool(rng.random() < 0.5)
            c = rng.uniform(-inner, inner, 3)
            if is_cylinder:
                c[2] = 0.0
            if np.linalg.norm(c) + r + team_radius + margin > inner:
                continue
            ok = True
            for other, oc in zip(obstacles, centres, strict=True):
                # a cylinder is infinite in z: only the horizontal distance counts
                either_cyl = is_cylinder or isinstance(other, Cylinder)
                d = np.linalg.norm((c - oc)[:2] if either_cyl else c - oc)
                if d < r + other.radius + 2.0 * team_radius + margin:
                    ok = False
                    break
            if ok:
                centres.append(c)
                obstacles.append(
                    Cylinder(float(c[0]), float(c[1]), r)
                    if is_cylinder
                    else Sphere((float(c[0]), float(c[1]), float(c[2])), r)
                )
        if len(obstacles) < count:
            continue
        for _ in range(1000):
            goal = rng.uniform(-inner, inner, 3)
            try:
                field = NavigationField(goal, ws, obstacles, team_radius)
            except ValueError:
                continue
            if PointField(field).clearance(goal) > margin:
                return goal, ws, obstacles


def test_random_scenes_have_no_local_minima_with_chosen_k() -> None:
    """``choose_k`` returns the smallest gain of its sequence 4 * 1.5^i that has no
    spurious minimum: every fresh start descends to the goal at the chosen k, and at the
    candidate before it (where there is one) some of its own starts get stuck; the scenes
    that need more than the default gain (k = 6) do have a minimum at the default."""
    rng = np.random.default_rng(20240611)
    k_start, factor, default_k = 4.0, 1.5, 6.0
    above_start = 0
    for scene in range(20):
        goal, ws, obstacles = _random_scene(rng)
        k = choose_k(goal, ws, obstacles, 1.0, k_start=k_start, factor=factor, seed=scene)
        steps = round(math.log(k / k_start, factor))
        assert k == pytest.approx(k_start * factor**steps), k  # a member of the sequence
        # verify on fresh starts, not the ones choose_k tuned on
        field = NavigationField(goal, ws, obstacles, 1.0, k=k)
        starts = sample_free_points(field, 200, rng)
        reached, final = descend(field, starts)
        assert np.all(reached), f"scene {scene}, k = {k}: stuck at {final[~reached][:3]}"
        if steps == 0:
            continue
        above_start += 1
        # choose_k's own starts (its seed) at the previous candidate: not all reach
        tuned = sample_free_points(
            NavigationField(goal, ws, obstacles, 1.0, k=k_start), 200, np.random.default_rng(scene)
        )
        before = NavigationField(goal, ws, obstacles, 1.0, k=k / factor)
        assert not np.all(descend(before, tuned)[0]), f"scene {scene}: k / 1.5 already works"
        if k > default_k:
            at_default = NavigationField(goal, ws, obstacles, 1.0, k=default_k)
            assert not np.all(descend(at_default, tuned)[0]), f"scene {scene} at the default"
    assert above_start > 0  # some scene makes the search go beyond its first candidate


def test_descend_detects_a_local_minimum_for_small_k() -> None:
    # two cylinders leave a 0.2 m gap (inflated) with the goal behind it; for small k the
    # repulsion wins on the far side and creates spurious minima near (-3..-5, 0, 0)
    ws = Workspace((0.0, 0.0, 0.0), 8.0)
    obstacles: list[Obstacle] = [Cylinder(0.0, 1.6, 0.5), Cylinder(0.0, -1.6, 0.5)]
    field_small = NavigationField((2.5, 0.0, 0.0), ws, obstacles, 1.0, k=1.0)
    starts = sample_free_points(field_small, 200, np.random.default_rng(7))
    reached, _ = descend(field_small, starts)
    assert not np.all(reached)
    k = choose_k((2.5, 0.0, 0.0), ws, obstacles, 1.0, k_start=1.0)
    assert k > 1.0
    reached, _ = descend(NavigationField((2.5, 0.0, 0.0), ws, obstacles, 1.0, k=k), starts)
    assert np.all(reached)


# ---------------------------------------------------------------- orientation, sequencing
def test_wrap_angle_range() -> None:
    a = np.array([-math.pi, math.pi, 3.0 * math.pi, -3.0 * math.pi, 0.0, 7.0, -7.0])
    w = wrap_angle(a)
    assert np.all((w > -math.pi) & (w <= math.pi))
    np.testing.assert_allclose(w[:4], math.pi)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)


def test_attitude_rate_saturates_and_takes_short_way() -> None:
    rate = attitude_rate([0.01, 3.1, -3.1], [0.0, -3.1, 3.1], gain=0.2, max_rate=0.05)
    # theta - theta_d = 6.2 wraps to 6.2 - 2 pi = -0.083 rad: the short way round
    np.testing.assert_allclose(
        rate, [-0.002, -0.2 * (6.2 - 2 * math.pi), 0.2 * (6.2 - 2 * math.pi)]
    )
    assert np.all(np.abs(attitude_rate([2.0, -2.0, 0.0], [0.0, 0.0, 0.0])) <= 0.05)


def test_euler_rate_matrix_matches_rotation_derivative() -> None:
    """The attitude law's Euler-angle rates are T(Theta) times the body angular velocity."""

    def rot(e: np.ndarray) -> np.ndarray:
        cr, sr = math.cos(e[0]), math.sin(e[0])
        cp, sp = math.cos(e[1]), math.sin(e[1])
        cy, sy = math.cos(e[2]), math.sin(e[2])
        rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        return rz @ ry @ rx

    e = np.array([0.3, -0.4, 1.1])
    de = np.array([0.05, -0.02, 0.04])
    h = 1e-6
    r_dot = (rot(e + h * de) - rot(e - h * de)) / (2 * h)
    skew = rot(e).T @ r_dot
    omega = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
    np.testing.assert_allclose(np.array(euler_rate_matrix(e)) @ omega, de, atol=1e-9)


# ---------------------------------------------------------------- 5. bad input
@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Cylinder(0.0, 0.0, -0.1), "radius"),
        (lambda: Sphere((0.0, 0.0, 0.0), -1.0), "radius"),
        (lambda: Workspace((0.0, 0.0, 0.0), -5.0), "radius"),
        (lambda: Workspace((0.0, 0.0, 0.0), 0.0), "radius"),
        (lambda: Cylinder(float("nan"), 0.0, 1.0), "finite"),
        (lambda: Sphere((0.0, float("nan"), 0.0), 1.0), "finite"),
        (lambda: Sphere((0.0, 0.0), 1.0), "shape"),
        (lambda: NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0, k=0.5), "k must"),
        (lambda: NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], -1.0), "team_radius"),
        (lambda: NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 5.0), "workspace"),
        (lambda: NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0, gain=0), "gain"),
        (
            lambda: NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0, max_speed=-1),
            "max_speed",
        ),
        (lambda: NavigationField((0, 0, math.nan), Workspace((0, 0, 0), 5), [], 1.0), "goal"),
        (lambda: NavigationField((0, 0), Workspace((0, 0, 0), 5), [], 1.0), "goal"),
        (
            lambda: NavigationField(
                (5.0, -5.0, 0.8), PAPER_WORKSPACE, PAPER_OBSTACLES, PAPER_TEAM_RADIUS
            ),
            "outside the free space",
        ),
        (lambda: NavigationField((4.5, 0, 0), Workspace((0, 0, 0), 5), [], 1.0), "outside"),
        (
            lambda: phi_batch(NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0), [0, 0]),
            "shape",
        ),
        (
            lambda: desired_velocity_batch(
                NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0), [[0.0, math.nan, 0.0]]
            ),
            "finite",
        ),
        (lambda: WaypointSequencer([[0, 0, 0, 0, 0, math.nan]]), "finite"),
        (lambda: WaypointSequencer([[0, 0, 0]]), "shape"),
        (
            lambda: WaypointNavigator(
                PAPER_WAYPOINTS, PAPER_WORKSPACE, PAPER_OBSTACLES, PAPER_TEAM_RADIUS, att_gain=-1
            ),
            "att_gain",
        ),
        (lambda: choose_k((0, 0, 0), Workspace((0, 0, 0), 5), [], 1.0, k_start=0.5), "k must"),
    ],
)
def test_bad_input_raises_value_error(make, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make()


def test_wrong_types_raise_type_error() -> None:
    with pytest.raises(TypeError, match="Workspace"):
        NavigationField((0, 0, 0), (0, 0, 0, 5), [], 1.0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="obstacle 0"):
        NavigationField((0, 0, 0), Workspace((0, 0, 0), 5), [(1, 1, 1)], 1.0)  # type: ignore[list-item]
