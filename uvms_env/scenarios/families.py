"""Scenario families: the paper's scenario and a seeded random family."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from uvms_env.dynamics import ObjectModel
from uvms_env.navigation import Cylinder, Sphere, Workspace
from uvms_env.scenarios.config import Scenario, obstacle_distance
from uvms_env.scenarios.geometry import (
    grasp_rotation,
    nominal_configuration,
    robot_radius,
    solve_grasp_ik,
    static_equilibrium,
    uvms_model,
)
from uvms_env.scenarios.overrides import SCENARIO_FIELDS, validate_overrides

# Keys every family accepts as overrides of make() (types and ranges: overrides.py);
# families may accept more (n_agents).
COMMON_OVERRIDES = SCENARIO_FIELDS
# The random family's team size when n_agents is not given: fixed, so that an
# environment built without it has the same agents every time.
RANDOM_DEFAULT_AGENTS = 2
PAPER_AGENTS = 2  # the paper's team, also the short family's
RANDOM_MAX_WAYPOINTS = 3  # the random family draws 1..3 waypoints


def _configure(
    name: str,
    shape: str,
    ring_radius: float,
    offsets: np.ndarray,
    yaws: np.ndarray,
    shares: np.ndarray,
    start: np.ndarray,
    waypoints: np.ndarray,
    obstacles: tuple,
    workspace: Workspace,
    **settings,
) -> Scenario:
    rotations = np.stack([grasp_rotation(y) for y in yaws])
    q_ik = np.stack(
        [
            solve_grasp_ik(start, l, r, nominal_configuration(start, l, y))
            for l, r, y in zip(offsets, rotations, yaws, strict=True)
        ]
    )
    q0 = _equilibrium_start(
        start.tobytes(), offsets.tobytes(), rotations.tobytes(), q_ik.tobytes(), shape, ring_radius
    )
    return Scenario(
        name=name,
        n_agents=len(offsets),
        object_shape=shape,
        ring_radius=ring_radius,
        grasp_offsets=offsets,
        grasp_rotations=rotations,
        load_shares=shares,
        object_start=start,
        waypoints=waypoints,
        obstacles=obstacles,
        workspace=workspace,
        initial_q=q0,
        robot_radius=robot_radius(),
        team_radius=team_radius(start, q0, shape, ring_radius),
        **settings,
    )


@functools.lru_cache(maxsize=256)
def _equilibrium_start(
    start: bytes, offsets: bytes, rotations: bytes, q_ik: bytes, shape: str, ring: float
) -> np.ndarray:
    """Cached by value: seeded families often share a start (e.g. every ``short`` task)."""
    n = len(np.frombuffer(offsets)) // 3
    q0, _ = static_equilibrium(
        np.frombuffer(start).copy(),
        np.frombuffer(offsets).reshape(n, 3),
        np.frombuffer(rotations).reshape(n, 3, 3),
        np.frombuffer(q_ik).reshape(n, 10),
        ObjectModel(shape, ring),
    )
    q0.setflags(write=False)
    return q0


def team_radius(x_o: np.ndarray, q: np.ndarray, shape: str, ring_radius: float) -> float:
    """Radius of the ball at the object centre holding every body (+0.1 m for arm motion)."""
    model = uvms_model()
    r_veh = model.params.vehicle.bounding_radius
    far = ObjectModel(shape, ring_radius).bounding_radius
    for qi in q:
        pts = np.array(model.body_points(qi)).T
        d = np.linalg.norm(pts - x_o[:3], axis=1)
        far = max(far, d[0] + r_veh, d[1:].max() + model.params.arm.tube_radius)
    return float(far + 0.1)


def paper(**settings) -> Scenario:
    """The paper's scenario: two UVMSs side by side carry a bar past three cylinders.

    Grasps 1.6 m apart on the 1.8 m bar, both vehicles heading along the object's x
    axis; obstacles, start pose, waypoints and load shares as in the paper.
    """
    n = settings.pop("n_agents", PAPER_AGENTS)
    if n != PAPER_AGENTS:
        raise ValueError(f"the paper scenario has exactly 2 agents, got n_agents={n}")
    return _configure(
        "paper",
        "bar",
        0.0,
        offsets=np.array([[0.0, 0.8, 0.0], [0.0, -0.8, 0.0]]),
        yaws=np.zeros(2),
        shares=np.array([0.5, 0.5]),
        start=np.array([-0.7, 0.0, 0.72, 0.04, -0.07, 0.0]),
        waypoints=np.array(
            [[6.0, -6.0, 0.85, 0, 0, 0], [7.5, 1.5, 0.78, 0, 0, 0], [12.0, 6.5, 0.65, 0, 0, 0]]
        ),
        obstacles=(Cylinder(4.0, -4.5, 0.6), Cylinder(9.0, -1.5, 0.6), Cylinder(9.0, 5.0, 0.6)),
        workspace=Workspace((5.5, 0.5, 0.75), 14.0),
        **settings,
    )


def random(**settings) -> Scenario:
    """Seeded random family: N = 2..6 robots around a ring, random start, goal, obstacles.

    ``n_agents`` defaults to 2 (``RANDOM_DEFAULT_AGENTS``) whatever the seed: the team
    size is never drawn. Without a ``seed`` the geometry is a fresh random draw.

    Robots face the ring's centre from outside at random angles (neighbours at least
    2 r_bar apart), with heterogeneous load shares in [0.5/N, 1.5/N]. One to three
    waypoints, two to five obstacles (vertical cylinders and spheres) kept clear of the
    start and every waypoint by the team radius.
    """
    seed = settings.get("seed")
    rng = np.random.default_rng(seed)
    rng.integers(2, 7)  # formerly the default team size; still drawn: seeded geometries kept
    n = settings.pop("n_agents", RANDOM_DEFAULT_AGENTS)
    if not 2 <= n <= 6:
        raise ValueError(f"the random family has 2..6 agents, got n_agents={n}")
    r_bar = robot_radius()
    ring = max(1.0, 1.1 * r_bar / np.sin(np.pi / n))
    slack = 2 * np.arcsin(min(1.0, 1.1 * r_bar / ring))  # min angular gap between grasps
    spare = 2 * np.pi - n * slack
    gaps = slack + spare * rng.dirichlet(np.ones(n))
    angles = rng.uniform(0, 2 * np.pi) + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    offsets = np.stack([ring * np.cos(angles), ring * np.sin(angles), np.zeros(n)], axis=1)
    yaws = angles + np.pi + rng.uniform(-0.3, 0.3, n)
    shares = rng.uniform(0.5, 1.5, n)
    shares = shares / shares.sum()

    start = np.array([0.0, 0.0, rng.uniform(0.8, 2.0), 0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    q_probe = np.stack(
        [nominal_configuration(start, l, y) for l, y in zip(offsets, yaws, strict=True)]
    )
    r_team = team_radius(start, q_probe, "ring", ring) + 0.2
    n_wp = int(rng.integers(1, RANDOM_MAX_WAYPOINTS + 1))
    waypoints = np.zeros((n_wp, 6))
    pos = start[:3]
    for k in range(n_wp):
        heading = rng.uniform(-np.pi, np.pi)
        pos = pos + np.array(
            [*(rng.uniform(4, 8) * np.array([np.cos(heading), np.sin(heading)])), 0]
        )
        pos[2] = rng.uniform(0.8, 2.0)
        waypoints[k, :3] = pos
        waypoints[k, 5] = rng.uniform(-0.5, 0.5)
    keep_clear = np.vstack([start[:3], waypoints[:, :3]])
    center = keep_clear.mean(axis=0)
    radius = float(np.max(np.linalg.norm(keep_clear - center, axis=1))) + 2 * r_team + 2.0
    obstacles: list[Cylinder | Sphere] = []
    for _ in range(200):
        if len(obstacles) >= int(rng.integers(2, 6)):
            break
        r_obs = float(rng.uniform(0.3, 1.0))
        c = center + rng.uniform(-1, 1, 3) * np.array([radius * 0.6, radius * 0.6, 0.5])
        obs = (
            Cylinder(float(c[0]), float(c[1]), r_obs)
            if rng.random() < 0.6
            else Sphere(tuple(c), r_obs)
        )
        if np.min(obstacle_distance(keep_clear, obs)) < r_team + 0.5:
            continue
        if any(_too_close(obs, o, r_team) for o in obstacles):
            continue
        obstacles.append(obs)
    settings.setdefault("max_steps", 3000)
    return _configure(
        "random",
        "ring",
        ring,
        offsets,
        yaws,
        shares,
        start,
        waypoints,
        tuple(obstacles),
        Workspace(tuple(center), radius),
        **settings,
    )


def _too_close(a: Cylinder | Sphere, b: Cylinder | Sphere, r_team: float) -> bool:
    """Obstacles must leave a gap the team can pass through (sphere-world assumption)."""
    ca = np.array([a.x, a.y, 0.0]) if isinstance(a, Cylinder) else np.asarray(a.center)
    cb = np.array([b.x, b.y, 0.0]) if isinstance(b, Cylinder) else np.asarray(b.center)
    if isinstance(a, Cylinder) or isinstance(b, Cylinder):
        ca, cb = ca * [1, 1, 0], cb * [1, 1, 0]
    return float(np.linalg.norm(ca - cb)) < a.radius + b.radius + 2 * r_team


def short(**settings) -> Scenario:
    """A learning-sized task: the paper's team and start, one waypoint 2 m away in a seeded
    random horizontal direction (depth and heading unchanged), no obstacles, 300 periods
    (36 s; the navigation reference needs ~12 s). The paper scenario's first leg takes
    ~45 s and passes an obstacle; this variant makes RL on 2 CPU cores feasible."""
    n = settings.pop("n_agents", PAPER_AGENTS)
    if n != PAPER_AGENTS:
        raise ValueError(f"the short scenario has exactly 2 agents, got n_agents={n}")
    rng = np.random.default_rng(settings.get("seed"))
    start = np.array([-0.7, 0.0, 0.72, 0.04, -0.07, 0.0])
    heading = rng.uniform(-np.pi, np.pi)
    goal = start.copy()
    goal[:2] += 2.0 * np.array([np.cos(heading), np.sin(heading)])
    goal[3:5] = 0.0
    settings.setdefault("max_steps", 300)
    return _configure(
        "short",
        "bar",
        0.0,
        offsets=np.array([[0.0, 0.8, 0.0], [0.0, -0.8, 0.0]]),
        yaws=np.zeros(2),
        shares=np.array([0.5, 0.5]),
        start=start,
        waypoints=goal[None],
        obstacles=(),
        workspace=Workspace((-0.7, 0.0, 0.72), 8.0),
        **settings,
    )


FAMILIES: dict[str, Callable[..., Scenario]] = {"paper": paper, "random": random, "short": short}
# The families whose geometry is drawn from the seed (``reset(seed=s)`` of an environment
# then sets geometry s); the paper's is fixed.
SEEDED_FAMILIES = ("random", "short")


def default_agents(family: str) -> int:
    """The team size of ``family`` when ``n_agents`` is not given."""
    return RANDOM_DEFAULT_AGENTS if family == "random" else PAPER_AGENTS


def max_waypoints(family: str | None, scenario: Scenario) -> int:
    """Room for waypoints that every geometry of ``family`` fits in (``scenario``: one
    of them; a built Scenario, family None, keeps its own)."""
    return RANDOM_MAX_WAYPOINTS if family == "random" else len(scenario.waypoints)


def make(name: str = "paper", **overrides) -> Scenario:
    """Build a scenario of family ``name`` with keyword overrides, validated against the
    table ``uvms_env.scenarios.overrides.SCENARIO_OVERRIDES`` (types, ranges, meanings:
    docs/options.md, "Environment options"); a wrong type raises TypeError, a value out of
    range or an unknown key ValueError, naming the key and what is allowed."""
    if not isinstance(name, str) or name not in FAMILIES:
        raise ValueError(f"unknown scenario {name!r}; known: {sorted(FAMILIES)}")
    return FAMILIES[name](**validate_overrides(overrides))


def replace(scenario: Scenario, **changes) -> Scenario:
    """A copy of a scenario with some fields changed, validated again."""
    return dataclasses.replace(scenario, **changes)
