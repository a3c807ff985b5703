"""The random family's bars and turning courses: seeded, one bar per team size that every
consumer sees alike, robots apart, obstacles on the path, the paper's task held out."""

from __future__ import annotations

import itertools
import types

import casadi as cs
import numpy as np
import pytest

import uvms_env
from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.payload import object_key, object_size, object_tag
from uvms_env.models import load_parameters
from uvms_env.policy import AgentSpec
from uvms_env.robot.priors import object_model
from uvms_env.scenarios import current_within_reach, families, held_out, make, obstacle_distance
from uvms_env.scenarios.bank import GeometryBank
from uvms_env.scenarios.geometry import nominal_hand, robot_radius
from uvms_env.scenarios.overrides import RANDOM_MAX_AGENTS
from uvms_env.sim.simulator import Simulator

SEEDS = range(60)
TEAM_SIZES = range(2, RANDOM_MAX_AGENTS + 1)  # every team the random family draws


def _heading(rotation: np.ndarray) -> float:
    """A robot's heading in the object frame from its grasp rotation R_Oi."""
    rz = rotation @ nominal_hand()[1].T
    return float(np.arctan2(rz[1, 0], rz[0, 0]))


@pytest.fixture
def drawn(monkeypatch):
    """``random``'s draws without the grasp solves: what it would configure, as a record."""

    def record(name, shape, size, offsets, yaws, shares, start, waypoints, obstacles, ws, **kw):
        return types.SimpleNamespace(
            settings=kw, **{k: v for k, v in locals().items() if k != "kw"}
        )

    monkeypatch.setattr(families, "_configure", record)
    monkeypatch.setattr(families, "team_radius", lambda *args: 1.5)
    return lambda **kw: families.random(**kw)


# ------------------------------------------------------------------- the object's size


def test_one_number_names_each_object_and_every_consumer_builds_the_same_bar():
    bar_length = load_parameters().object.bar_length
    assert object_key("bar", 0.0) == object_key("bar", bar_length) == 0.0
    assert object_key("bar", 5.0) == object_key("bar", -5.0) == -5.0
    assert object_key("ring", 1.2) == 1.2
    assert object_size("bar", bar_length) == 0.0 and object_size("bar", -8.2) == 8.2
    for key in (0.0, -5.0, 1.2):
        cs.Function(f"f_{object_tag(key)}", [cs.SX.sym("x")], [0])  # a valid compiled name
    for n in TEAM_SIZES:
        s = make("random", seed=n, n_agents=n, object="bar")
        length = load_parameters().object.random_bar_length(n)
        spec = AgentSpec.from_scenario(s, 0)
        assert spec.object_key == s.object_key == object_key("bar", length)
        for model in (
            ObjectModel(s.object_shape, s.object_size),  # simulator, batched engine, reach
            object_model(s.object_key),  # priors, memory
            ObjectModel(spec.object_shape, spec.object_key),  # expert's OCP, filter
        ):
            assert model.length == pytest.approx(length)
            assert model.strips.lengths.max() <= 0.225 + 1e-9


def test_a_bar_scenario_simulates_with_its_own_bar():
    s = make("random", seed=4, n_agents=3, object="bar")
    sim = Simulator(s)
    assert sim.object.length == pytest.approx(load_parameters().object.random_bar_length(3))
    assert sim.grasp_error()[0].max() < 1e-9
    assert np.all(np.abs(sim.holding_inputs()) <= sim.tau_max)


# ------------------------------------------------------------------- teams


def test_bar_draws_are_seeded(drawn):
    for course in ("open", "turns", "mixed"):
        a = drawn(seed=3, n_agents=4, object="bar", course=course)
        b = drawn(seed=3, n_agents=4, object="bar", course=course)
        c = drawn(seed=4, n_agents=4, object="bar", course=course)
        for field in ("offsets", "yaws", "shares", "start", "waypoints"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
        assert a.obstacles == b.obstacles
        assert not np.array_equal(a.waypoints[:1], c.waypoints[:1])


@pytest.mark.parametrize("n", TEAM_SIZES)
def test_robots_stand_apart_on_their_bar_in_their_formation(drawn, n):
    length = load_parameters().object.random_bar_length(n)
    gap = families.BAR_GAP * robot_radius()
    formations = set()
    for seed in SEEDS:
        d = drawn(seed=seed, n_agents=n, object="bar")
        assert d.shape == "bar" and d.size == pytest.approx(length)
        y = d.offsets[:, 1]
        assert np.all(d.offsets[:, [0, 2]] == 0)  # on the bar's axis
        assert np.all(np.abs(y) <= length / 2 - families.BAR_END_MARGIN + 1e-12)
        assert np.min(np.diff(np.sort(y))) >= gap - 1e-12  # balls of r_bar apart
        assert d.shares.sum() == pytest.approx(1.0) and np.all(d.shares > 0)
        yaw = np.angle(np.exp(1j * d.yaws[np.argsort(y)]))
        ends = np.isclose(np.abs(yaw[[0, -1]]), np.pi / 2, atol=families.BAR_YAW_JITTER)
        if ends.all() and yaw[0] > 0 > yaw[-1]:  # both outermost face along, inwards
            formations.add("ends")
            off = np.angle(np.exp(2j * yaw[1:-1])) / 2  # the middles' heading modulo pi
            assert np.all(np.abs(off) <= families.BAR_YAW_JITTER)  # side by side
        else:
            across = np.abs(np.abs(yaw) - np.pi) <= families.BAR_YAW_JITTER
            assert np.all(across | (np.abs(yaw) <= families.BAR_YAW_JITTER))
            formations.add("side" if not across.any() or across.all() else "across")
    # teams beyond BAR_SIDE_BY_SIDE_MAX always hold their bar at the ends
    assert formations == ({"side", "across", "ends"} if n == 2 else {"ends"})


@pytest.mark.parametrize("n", [2, 3, 6])
def test_built_bar_teams_do_not_overlap(n):
    """Vehicle spheres apart, and the bar clear of every hull box (inflated by the tube)."""
    params = load_parameters()
    half = np.asarray(params.vehicle.box) / 2 + params.object.tube_radius
    for seed in range(3):
        s = make("random", seed=seed, n_agents=n, object="bar")
        veh = s.initial_q[:, :3]
        d = np.linalg.norm(veh[:, None] - veh[None], axis=-1) + np.eye(n) * 1e9
        assert d.min() >= 2 * params.vehicle.bounding_radius
        model = ObjectModel(s.object_shape, s.object_size)
        (a, b) = model.segments[0]
        rot_o = _rot(s.object_start[3:])
        points = s.object_start[:3] + (a + np.linspace(0, 1, 400)[:, None] * (b - a)) @ rot_o.T
        for q in s.initial_q:
            body = (points - q[:3]) @ _rot(q[3:6])  # into the vehicle frame
            assert not np.any(np.all(np.abs(body) < half, axis=1)), (seed, n)


def _rot(rpy: np.ndarray) -> np.ndarray:
    from uvms_env.dynamics.spatial import rot_zyx

    return np.array(rot_zyx(np.asarray(rpy, float)))


@pytest.mark.parametrize("n", [2, 4, 6])
def test_the_mild_current_is_within_reach_of_bar_teams(n):
    s = make("random", seed=1, n_agents=n, object="bar", current="mild")
    assert current_within_reach(s)[0]


# ------------------------------------------------------------------- courses


def test_turning_courses_put_an_obstacle_across_each_leg(drawn):
    blocked = legs = 0
    for seed in SEEDS:
        for obj in ("ring", "bar"):
            d = drawn(seed=seed, n_agents=3, object=obj, course="turns")
            points = np.vstack([d.start[:3], d.waypoints[:, :3]])
            assert 2 <= len(d.waypoints) <= families.RANDOM_MAX_WAYPOINTS
            r_team = 1.5 + 0.2  # the fixture's team radius, as random() pads it
            for obs in d.obstacles:  # the family's clearance rule
                assert np.min(obstacle_distance(points, obs)) >= r_team + 0.5
            for a, b in itertools.pairwise(points):
                legs += 1
                line = a + np.linspace(0, 1, 200)[:, None] * (b - a)
                blocked += any(np.min(obstacle_distance(line, o)) < r_team for o in d.obstacles)
            heading = np.angle(np.exp(1j * (d.waypoints[:, 5] - d.start[5])))
            assert np.all(np.abs(heading) <= 0.5)  # the object keeps its heading
    assert blocked / legs > 0.9


def test_open_courses_keep_drawing_as_before_for_rings(drawn):
    """A ring's open course is the family's first: waypoint yaws in [-0.5, 0.5], absolute."""
    d = drawn(seed=11, n_agents=2)
    assert np.all(np.abs(d.waypoints[:, 5]) <= 0.5)
    b = drawn(seed=11, n_agents=2, object="bar")
    assert np.all(np.abs(np.angle(np.exp(1j * (b.waypoints[:, 5] - b.start[5])))) <= 0.5)


# ------------------------------------------------------------------- the held-out split


def _paper_course_from(start: np.ndarray, angle: float, mirror: bool) -> np.ndarray:
    """The paper's waypoints moved to ``start``, turned by ``angle`` (and mirrored)."""
    paper = np.array(families.PAPER_WAYPOINTS)
    rel = paper[:, :2] - np.array(families.PAPER_START)[:2]
    if mirror:
        rel = rel * [1, -1]
    c, s = np.cos(angle), np.sin(angle)
    out = paper.copy()
    out[:, :2] = start[:2] + rel @ np.array([[c, s], [-s, c]])
    return out


def test_the_paper_is_held_out_whatever_its_placement():
    assert held_out(make("paper"))
    start = np.array([3.0, -2.0, 1.0, 0, 0, 0.4])
    for angle in (0.0, 1.0, -2.5):
        for mirror in (False, True):
            wps = _paper_course_from(start, angle, mirror)
            assert families.paper_course_distance(start, wps) < 1e-9
    assert families.paper_course_distance(start, wps[:2]) == np.inf


def test_no_training_draw_is_the_papers_task(drawn):
    for seed in range(200):
        for course in ("open", "turns"):
            d = drawn(seed=seed, n_agents=2, object="bar", course=course)
            assert families.paper_course_distance(d.start, d.waypoints) >= 1.5


def test_a_draw_of_the_papers_course_is_drawn_again(drawn, monkeypatch):
    calls = []
    draw = families._turning_course

    def paper_first(rng, start, r_team):
        calls.append(1)
        if len(calls) == 1:  # the paper's course, laid from this start
            return _paper_course_from(start, 0.3, False), (), families.Workspace((0, 0, 0), 50)
        return draw(rng, start, r_team)

    monkeypatch.setattr(families, "_turning_course", paper_first)
    d = drawn(seed=5, n_agents=2, object="bar", course="turns")
    assert len(calls) == 2
    assert families.paper_course_distance(d.start, d.waypoints) >= 1.5


# ------------------------------------------------------------------- options


def test_bad_options_name_themselves():
    with pytest.raises(ValueError, match="object: expected one of 'ring', 'bar'"):
        make("random", object="box")
    with pytest.raises(TypeError, match="course"):
        make("random", course=1)
    with pytest.raises(ValueError, match="object: only the random family"):
        make("paper", object="bar")
    with pytest.raises(ValueError, match="course: only the random family"):
        make("short", course="turns")
    with pytest.raises(ValueError, match="object cannot be overridden on a built Scenario"):
        uvms_env.parallel_env(make("paper"), object="bar")


def test_the_bank_keeps_bars_apart_and_serves_them(tmp_path):
    rings = GeometryBank("random", 2, folder=tmp_path)
    bars = GeometryBank("random", 2, folder=tmp_path, overrides={"object": "bar", "seed": 3})
    assert "object-bar" in bars.folder.name and "object" not in rings.folder.name
    assert GeometryBank("random", 2, folder=tmp_path, overrides={"object": "ring"}).folder == (
        rings.folder
    )
    g = bars.get(3)
    built = make("random", seed=3, n_agents=2, object="bar", mismatch=0.1)
    mine = g.scenario_with({"object": "bar", "seed": 3, "mismatch": 0.1})
    assert mine.object_shape == "bar" and mine.mismatch == 0.1
    for field in ("initial_q", "grasp_offsets", "waypoints"):
        assert np.array_equal(getattr(mine, field), getattr(built, field)), field


def test_bar_episodes_get_longer_with_the_team(drawn):
    """A turning course's legs grow with the team: its episodes too, one length per size."""
    assert drawn(seed=1, n_agents=6).settings["max_steps"] == families.RANDOM_MAX_STEPS
    for n in TEAM_SIZES:
        for seed in (1, 2):
            d = drawn(seed=seed, n_agents=n, object="bar", course="mixed")
            expected = families.RANDOM_MAX_STEPS + families.BAR_EXTRA_STEPS * (n - 2)
            assert d.settings["max_steps"] == expected
