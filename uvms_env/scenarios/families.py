"""Scenario families: the paper's scenario, a seeded random family and a short one.

``random`` draws a team (N = 2..8 robots around a ring, or along a bar: its ``object``
option) and a course (obstacles off the path, or on it so that the path turns around
them: its ``course`` option) from the seed; its defaults (ring, open) draw what they
always drew. The paper's own geometry is held out of its draws (``held_out``).

May import: numpy, ``uvms_env.models``, ``uvms_env.dynamics``, ``uvms_env.navigation`` and
the sibling ``scenarios`` modules.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Callable

import numpy as np

from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.payload import object_size
from uvms_env.models import load_parameters
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
from uvms_env.scenarios.overrides import RANDOM_MAX_AGENTS, SCENARIO_FIELDS, validate_overrides

# Keys every family accepts as overrides of make() (types and ranges: overrides.py);
# families may accept more (n_agents; the random family's object and course).
COMMON_OVERRIDES = SCENARIO_FIELDS
# The random family's team size when n_agents is not given: fixed, so that an
# environment built without it has the same agents every time.
RANDOM_DEFAULT_AGENTS = 2
# ... and its object and course when not given: the draws of every committed result.
RANDOM_DEFAULT_OBJECT = "ring"
RANDOM_DEFAULT_COURSE = "open"
PAPER_AGENTS = 2  # the paper's team, also the short family's
RANDOM_MAX_WAYPOINTS = 3  # the random family draws 1..3 waypoints
RANDOM_MAX_STEPS = 3000  # the random family's episode length, periods
# ... plus this many per robot beyond two with a bar: a turning course's legs grow with
# the team radius (about half the bar), and the full-information NMPC took up to 2767
# periods on a 6.6 m bar's course. One length per team size: an environment has one.
BAR_EXTRA_STEPS = 500

# The paper's geometry (paper()); the random family never draws it (held_out).
PAPER_START = (-0.7, 0.0, 0.72, 0.04, -0.07, 0.0)
PAPER_OFFSETS = ((0.0, 0.8, 0.0), (0.0, -0.8, 0.0))
PAPER_WAYPOINTS = (
    (6.0, -6.0, 0.85, 0.0, 0.0, 0.0),
    (7.5, 1.5, 0.78, 0.0, 0.0, 0.0),
    (12.0, 6.5, 0.65, 0.0, 0.0, 0.0),
)
PAPER_CYLINDERS = ((4.0, -4.5, 0.6), (9.0, -1.5, 0.6), (9.0, 5.0, 0.6))
# A two-robot bar draw whose course lies within this of the paper's (every waypoint, in
# the plane, after laying its start and first leg onto the paper's, or onto their mirror
# image) is drawn again: the paper's task stays out of any training draw.
PAPER_HOLDOUT_TOLERANCE = 1.5  # m
HOLDOUT_ATTEMPTS = 100

# Bars (object="bar"): the bar lies along the object's y axis, its length per team size
# from the parameter file (object.bar.random_lengths). Grasps on the bar's axis at least
# BAR_GAP r_bar apart (the paper's are 2.1 r_bar apart: 1.6 m) and BAR_END_MARGIN in from
# its ends, the spare length spread at random (Dirichlet, like the ring's gaps).
BAR_GAP = 2.05
BAR_END_MARGIN = 0.1  # m, the paper's
BAR_YAW_JITTER = 0.15  # rad, each robot's heading about its formation's
# Formations and their odds: "side": side by side, every robot heading across the bar
# the same way (the paper's team); "across": side by side, each from a random side of the
# bar; "ends": the outermost two hold the bar's ends facing along it (end to end), the
# others side by side, each from a random side.
BAR_FORMATIONS = {"side": 0.5, "across": 0.25, "ends": 0.25}
# Side-by-side formations up to this team size only; larger teams hold their bar "ends".
# Why: a robot tilts the object only about its own lateral axis, by heaving its vehicle
# 0.4 m behind its grasp (vehicles roll and pitch passively; the wrists give 2 N m), and
# no robot's local model can express robots heaving apart. Side by side every lateral
# axis runs along the bar and nothing holds the bar's roll (about the axis across it):
# three robots side by side on a 5 m bar let it roll past 60 degrees; at the ends, facing
# along the bar, two robots hold it.
BAR_SIDE_BY_SIDE_MAX = 2

# Turning courses (course="turns"): two or three legs, each turning TURN_ANGLE from the
# last (either way), each with one obstacle near its middle whose inflated ball (radius
# plus team radius) the straight leg would cross, so that the path must turn around it,
# as the paper's legs turn around its cylinders. Legs are long enough for an obstacle to
# clear both ends by the family's keep-clear distance.
TURN_ANGLE = (0.5, 2.0)  # rad
TURN_LEG_MIN = 6.0  # m, whatever the team
TURN_LEG_SPREAD = 3.0  # m, legs in [shortest, shortest + spread]
TURN_OBSTACLE_RADIUS = (0.4, 0.8)  # m
TURN_BLOCK = 0.7  # lateral offset from the leg, in (obstacle radius + team radius)
TURN_CYLINDER_ODDS = 0.75  # cylinders like the paper's; the rest spheres at the leg's depth
TURN_EXTRA_OBSTACLES = 2  # up to this many more, off the path (the open course's rule)
TURN_TRIES = 50  # draws per obstacle before its leg stays open


def _configure(
    name: str,
    shape: str,
    size: float,
    offsets: np.ndarray,
    yaws: np.ndarray,
    shares: np.ndarray,
    start: np.ndarray,
    waypoints: np.ndarray,
    obstacles: tuple,
    workspace: Workspace,
    **settings,
) -> Scenario:
    size = object_size(shape, size)  # one value per object: one compiled name
    rotations = np.stack([grasp_rotation(y) for y in yaws])
    q_ik = np.stack(
        [
            solve_grasp_ik(start, l, r, nominal_configuration(start, l, y))
            for l, r, y in zip(offsets, rotations, yaws, strict=True)
        ]
    )
    q0 = _equilibrium_start(
        start.tobytes(), offsets.tobytes(), rotations.tobytes(), q_ik.tobytes(), shape, size
    )
    return Scenario(
        name=name,
        n_agents=len(offsets),
        object_shape=shape,
        object_size=size,
        grasp_offsets=offsets,
        grasp_rotations=rotations,
        load_shares=shares,
        object_start=start,
        waypoints=waypoints,
        obstacles=obstacles,
        workspace=workspace,
        initial_q=q0,
        robot_radius=robot_radius(),
        team_radius=team_radius(start, q0, shape, size),
        **settings,
    )


@functools.lru_cache(maxsize=256)
def _equilibrium_start(
    start: bytes, offsets: bytes, rotations: bytes, q_ik: bytes, shape: str, size: float
) -> np.ndarray:
    """Cached by value: seeded families often share a start (e.g. every ``short`` task)."""
    n = len(np.frombuffer(offsets)) // 3
    q0, _ = static_equilibrium(
        np.frombuffer(start).copy(),
        np.frombuffer(offsets).reshape(n, 3),
        np.frombuffer(rotations).reshape(n, 3, 3),
        np.frombuffer(q_ik).reshape(n, 10),
        ObjectModel(shape, size),
    )
    q0.setflags(write=False)
    return q0


def team_radius(x_o: np.ndarray, q: np.ndarray, shape: str, size: float) -> float:
    """Radius of the ball at the object centre holding every body (+0.1 m for arm motion)."""
    model = uvms_model()
    r_veh = model.params.vehicle.bounding_radius
    far = ObjectModel(shape, size).bounding_radius
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
    _paper_team_only("paper", settings)
    return _with_paper_team(
        "paper",
        waypoints=np.array(PAPER_WAYPOINTS, dtype=float),
        obstacles=tuple(Cylinder(*c) for c in PAPER_CYLINDERS),
        workspace=Workspace((5.5, 0.5, 0.75), 14.0),
        **settings,
    )


def _paper_team_only(family: str, settings: dict) -> None:
    """ValueError unless ``settings`` keep the paper's team: two robots, and neither the
    object nor the course drawn."""
    n = settings.pop("n_agents", PAPER_AGENTS)
    if n != PAPER_AGENTS:
        raise ValueError(f"the {family} scenario has exactly 2 agents, got n_agents={n}")
    _refuse_random_options(family, settings)


def _with_paper_team(name: str, **course) -> Scenario:
    """The paper's team at its start: the bar grasped side by side, equal shares; the
    course (waypoints, obstacles, workspace) and settings as given."""
    return _configure(
        name,
        "bar",
        0.0,
        offsets=np.array(PAPER_OFFSETS),
        yaws=np.zeros(2),
        shares=np.array([0.5, 0.5]),
        start=np.array(PAPER_START),
        **course,
    )


def _refuse_random_options(family: str, settings: dict) -> None:
    for key in ("object", "course"):
        if key in settings:
            raise ValueError(
                f"{key}: only the random family draws its {key}; the {family} scenario's "
                f"is fixed (got {key}={settings[key]!r})"
            )


def random(**settings) -> Scenario:
    """Seeded random family: N = 2..8 robots carry a ring or a bar from a random start
    through one to three waypoints among obstacles.

    ``n_agents`` defaults to 2 (``RANDOM_DEFAULT_AGENTS``) whatever the seed: the team
    size is never drawn. Without a ``seed`` the geometry is a fresh random draw.

    ``object="ring"`` (default): robots face the ring's centre from outside at random
    angles (neighbours at least 2 r_bar apart). ``object="bar"``: robots hold the team
    size's bar (``Parameters.object.random_bar_length``) in a drawn formation
    (``BAR_FORMATIONS``). Load shares are heterogeneous in [0.5/N, 1.5/N].

    ``course="open"`` (default): one to three waypoints in random directions, two to five
    obstacles (vertical cylinders and spheres) kept clear of the start and every waypoint
    by the team radius. ``course="turns"``: two or three legs that turn, an obstacle on
    each so that the path turns around it (``TURN_*``); ``course="mixed"``: either, by
    seed. A two-robot bar never gets the paper's course (``held_out``).
    """
    seed = settings.get("seed")
    rng = np.random.default_rng(seed)
    rng.integers(2, 7)  # formerly the default team size; still drawn: seeded geometries kept
    n = settings.pop("n_agents", RANDOM_DEFAULT_AGENTS)
    if not 2 <= n <= RANDOM_MAX_AGENTS:
        raise ValueError(f"the random family has 2..{RANDOM_MAX_AGENTS} agents, got n_agents={n}")
    shape = settings.pop("object", RANDOM_DEFAULT_OBJECT)
    course = settings.pop("course", RANDOM_DEFAULT_COURSE)
    draw_team = _ring_team if shape == "ring" else _bar_team
    offsets, yaws, shares, size = draw_team(rng, n)

    start = np.array([0.0, 0.0, rng.uniform(0.8, 2.0), 0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    q_probe = np.stack(
        [nominal_configuration(start, l, y) for l, y in zip(offsets, yaws, strict=True)]
    )
    r_team = team_radius(start, q_probe, shape, size) + 0.2
    if course == "mixed":
        course = "turns" if rng.random() < 0.5 else "open"
    draw_course = _turning_course if course == "turns" else _open_course
    for _ in range(HOLDOUT_ATTEMPTS):
        waypoints, obstacles, workspace = draw_course(rng, start, r_team)
        if shape == "bar" or course == "turns":
            # the object keeps about its start heading, as the paper's does: turning a
            # long bar half around is a task of its own (its ends sweep metres)
            waypoints[:, 5] = _wrap(start[5] + waypoints[:, 5])
        if not _paper_team(shape, size, n) or not _paper_course(start, waypoints):
            break
    else:
        raise RuntimeError(f"no course off the paper's in {HOLDOUT_ATTEMPTS} draws")
    extra = BAR_EXTRA_STEPS * (n - 2) if shape == "bar" else 0
    settings.setdefault("max_steps", RANDOM_MAX_STEPS + extra)
    return _configure(
        "random",
        shape,
        size,
        offsets,
        yaws,
        shares,
        start,
        waypoints,
        obstacles,
        workspace,
        **settings,
    )


Team = tuple[np.ndarray, np.ndarray, np.ndarray, float]  # offsets, yaws, load shares, size


def _ring_team(rng: np.random.Generator, n: int) -> Team:
    """N robots around the team size's ring, facing its centre from outside."""
    r_bar = robot_radius()
    ring = max(1.0, 1.1 * r_bar / np.sin(np.pi / n))
    slack = 2 * np.arcsin(min(1.0, 1.1 * r_bar / ring))  # min angular gap between grasps
    spare = 2 * np.pi - n * slack
    gaps = slack + spare * rng.dirichlet(np.ones(n))
    angles = rng.uniform(0, 2 * np.pi) + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    offsets = np.stack([ring * np.cos(angles), ring * np.sin(angles), np.zeros(n)], axis=1)
    yaws = angles + np.pi + rng.uniform(-0.3, 0.3, n)
    shares = rng.uniform(0.5, 1.5, n)
    return offsets, yaws, shares / shares.sum(), float(ring)


def bar_grasp_room(n: int) -> tuple[float, float, float]:
    """(bar length, least gap between grasps, spare length) of the random family's bar
    for ``n`` robots; ValueError if the parameter file's bar is too short for them."""
    length = load_parameters().object.random_bar_length(n)
    gap = BAR_GAP * robot_radius()
    spare = length - 2 * BAR_END_MARGIN - (n - 1) * gap
    if spare < 0:
        raise ValueError(
            f"a {length} m bar cannot hold {n} grasps {gap:.3f} m apart and {BAR_END_MARGIN} m "
            "in from its ends: lengthen object.bar.random_lengths"
        )
    return length, gap, spare


def _bar_team(rng: np.random.Generator, n: int) -> Team:
    """N robots along the team size's bar in a drawn formation (``BAR_FORMATIONS``); the
    robots' order along the bar is shuffled."""
    length, gap, spare = bar_grasp_room(n)
    parts = rng.dirichlet(np.ones(n + 1))  # the spare length: before, between, after
    y = -length / 2 + BAR_END_MARGIN + spare * np.cumsum(parts[:n]) + gap * np.arange(n)
    formation = "ends"
    if n <= BAR_SIDE_BY_SIDE_MAX:
        names = list(BAR_FORMATIONS)
        formation = names[int(rng.choice(len(names), p=list(BAR_FORMATIONS.values())))]
    jitter = rng.uniform(-BAR_YAW_JITTER, BAR_YAW_JITTER, n)
    yaws = jitter.copy()  # 0: heading across the bar, along +x
    if formation != "side":
        yaws += np.pi * rng.integers(0, 2, n)  # each from a random side
    if formation == "ends":
        yaws[0] = np.pi / 2 + jitter[0]  # at the -y end, facing +y along the bar
        yaws[-1] = -np.pi / 2 + jitter[-1]
    order = rng.permutation(n)
    offsets = np.stack([np.zeros(n), y, np.zeros(n)], axis=1)[order]
    shares = rng.uniform(0.5, 1.5, n)
    return offsets, yaws[order], shares / shares.sum(), length


Course = tuple[np.ndarray, tuple, Workspace]  # waypoints, obstacles, workspace


def _open_course(rng: np.random.Generator, start: np.ndarray, r_team: float) -> Course:
    """One to three waypoints in random directions; two to five obstacles kept clear of
    the start and every waypoint (the family's draws since its first version)."""
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
        obs = _off_path_obstacle(rng, center, radius)
        if _placeable(obs, obstacles, keep_clear, r_team):
            obstacles.append(obs)
    return waypoints, tuple(obstacles), Workspace(tuple(center), radius)


def _off_path_obstacle(
    rng: np.random.Generator, center: np.ndarray, radius: float
) -> Cylinder | Sphere:
    r_obs = float(rng.uniform(0.3, 1.0))
    c = center + rng.uniform(-1, 1, 3) * np.array([radius * 0.6, radius * 0.6, 0.5])
    if rng.random() < 0.6:
        return Cylinder(float(c[0]), float(c[1]), r_obs)
    return Sphere(tuple(c), r_obs)


def _placeable(
    obs: Cylinder | Sphere, obstacles: list, keep_clear: np.ndarray, r_team: float
) -> bool:
    """Clear of the start and the waypoints, and of the other obstacles by a passage."""
    if np.min(obstacle_distance(keep_clear, obs)) < r_team + 0.5:
        return False
    return not any(_too_close(obs, o, r_team) for o in obstacles)


def _turning_course(rng: np.random.Generator, start: np.ndarray, r_team: float) -> Course:
    """Two or three legs that turn, each with an obstacle its straight line would hit
    (``TURN_*``), up to ``TURN_EXTRA_OBSTACLES`` more off the path."""
    r_lo, r_hi = TURN_OBSTACLE_RADIUS
    shortest = max(TURN_LEG_MIN, 2 * (r_team + 0.5 + r_hi) + 1.0)
    n_wp = int(rng.integers(2, RANDOM_MAX_WAYPOINTS + 1))
    waypoints = np.zeros((n_wp, 6))
    heading = rng.uniform(-np.pi, np.pi)
    pos = start[:3]
    for k in range(n_wp):
        if k:
            heading += rng.choice((-1.0, 1.0)) * rng.uniform(*TURN_ANGLE)
        step = rng.uniform(shortest, shortest + TURN_LEG_SPREAD)
        pos = pos + step * np.array([np.cos(heading), np.sin(heading), 0.0])
        pos[2] = rng.uniform(0.8, 2.0)
        waypoints[k, :3] = pos
        waypoints[k, 5] = rng.uniform(-0.5, 0.5)  # about the start's: random() adds it
    keep_clear = np.vstack([start[:3], waypoints[:, :3]])
    obstacles: list[Cylinder | Sphere] = []
    for a, b in itertools.pairwise(keep_clear):
        along = (b - a) * [1, 1, 0]
        normal = np.array([-along[1], along[0], 0.0]) / np.linalg.norm(along)
        for _ in range(TURN_TRIES):
            r_obs = float(rng.uniform(r_lo, r_hi))
            side = rng.uniform(-TURN_BLOCK, TURN_BLOCK) * (r_obs + r_team)
            c = a + rng.uniform(0.35, 0.65) * (b - a) + side * normal
            obs = (
                Cylinder(float(c[0]), float(c[1]), r_obs)
                if rng.random() < TURN_CYLINDER_ODDS
                else Sphere(tuple(c), r_obs)
            )
            if _placeable(obs, obstacles, keep_clear, r_team):
                obstacles.append(obs)
                break
    center = keep_clear.mean(axis=0)
    radius = float(np.max(np.linalg.norm(keep_clear - center, axis=1))) + 2 * r_team + 2.0
    for _ in range(int(rng.integers(0, TURN_EXTRA_OBSTACLES + 1))):
        for _ in range(TURN_TRIES):
            obs = _off_path_obstacle(rng, center, radius)
            if _placeable(obs, obstacles, keep_clear, r_team):
                obstacles.append(obs)
                break
    return waypoints, tuple(obstacles), Workspace(tuple(center), radius)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(angle)))


def _paper_team(shape: str, size: float, n: int) -> bool:
    """Two robots on the paper's bar: the team of the paper's task, whatever the grasps
    (on that bar they can only sit about where the paper's do)."""
    return shape == "bar" and n == PAPER_AGENTS and object_size(shape, size) == 0.0


def paper_course_distance(start: np.ndarray, waypoints: np.ndarray) -> float:
    """How far a course is from the paper's (m): the largest planar distance between
    matching waypoints once the start sits on the paper's and the first leg points along
    the paper's first leg, the course or its mirror image, whichever is nearer; inf for
    another number of waypoints."""
    paper = np.asarray(PAPER_WAYPOINTS)
    if len(waypoints) != len(paper):
        return float("inf")
    mine = _leg_frame(np.asarray(start)[:2], np.asarray(waypoints)[:, :2])
    theirs = _leg_frame(np.asarray(PAPER_START)[:2], paper[:, :2])
    return float(
        min(np.max(np.linalg.norm(m - theirs, axis=1)) for m in (mine, mine * [1.0, -1.0]))
    )


def _leg_frame(start: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points`` from ``start``, in the frame whose x axis runs along the first leg."""
    rel = points - start
    c, s = rel[0] / np.linalg.norm(rel[0])
    return rel @ np.array([[c, -s], [s, c]])


def _paper_course(start: np.ndarray, waypoints: np.ndarray) -> bool:
    return paper_course_distance(start, waypoints) < PAPER_HOLDOUT_TOLERANCE


def held_out(scenario: Scenario) -> bool:
    """The held-out split: the paper's task, its team (two robots on its bar) on its
    course (within ``PAPER_HOLDOUT_TOLERANCE``). True for ``paper``; the random family
    draws again rather than produce one."""
    s = scenario
    return _paper_team(s.object_shape, s.object_size, s.n_agents) and _paper_course(
        s.object_start, s.waypoints
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
    _paper_team_only("short", settings)
    rng = np.random.default_rng(settings.get("seed"))
    start = np.array(PAPER_START)
    heading = rng.uniform(-np.pi, np.pi)
    goal = start.copy()
    goal[:2] += 2.0 * np.array([np.cos(heading), np.sin(heading)])
    goal[3:5] = 0.0
    settings.setdefault("max_steps", 300)
    return _with_paper_team(
        "short",
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
