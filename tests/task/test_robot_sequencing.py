"""Each robot's waypoint sequencer and navigation twist, and the team's sequencer with the
reward's potential and the goal test, computed inside the team kernel
(``uvms_env.task.team_kernel``), against an independent computation: the sequencing rule
written out in numpy on the kernel's own estimates (the robots') or the true object (the
team's), the potential and goal test in numpy, and the scene's own navigator
(``WaypointNavigator.casadi_function``, the waypoint's constants baked in)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uvms_env.dynamics import NU
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.navigation.task_navigator import WAYPOINT_TOLERANCE, task_navigator
from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT, OBSERVATION_STRUCTURE
from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.task.team_kernel import TeamKinematics
from uvms_env.task.team_rows import AT_GOAL, PASSED, POTENTIAL, POTENTIAL_AFTER, TEAM_SEQUENCER

WAYPOINT = OBSERVATION_STRUCTURE["waypoint"]
NAV = OBSERVATION_STRUCTURE["nav_velocity"]


def _reference(kin: TeamKinematics, scene, sequencers: np.ndarray) -> tuple:
    """The rule: a robot not done passes its waypoint within the tolerance of its own
    estimate; past the last one it is done. Then the twist towards its waypoint."""
    pose = kin.pose_estimate.copy()
    count = len(scene.waypoints)
    index, done = sequencers[:, 0].astype(int), sequencers[:, 1] > 0
    d = np.linalg.norm(pose[:, :3] - np.asarray(scene.waypoints)[index, :3], axis=1)
    near = ~done & (d < WAYPOINT_TOLERANCE)
    last = index + 1 >= count
    index = index + (near & ~last)
    done = done | (near & last)
    nav = task_navigator(scene.waypoints, scene.workspace, scene.obstacles, scene.team_radius)
    twist = [nav.casadi_function(int(i))(p) for i, p in zip(index, pose, strict=True)]
    return np.c_[index, done].astype(float), np.asarray(scene.waypoints)[index], np.hstack(twist).T


@pytest.mark.parametrize("family, seed", [("paper", 0), ("random", 3), ("random", 19)])
def test_kernel_sequences_and_navigates_as_the_rule_and_the_scenes_navigator(family, seed):
    """Waypoints moved onto a robot's estimate, so that some robots pass one (the last
    too) and others do not; done robots stay where they are."""
    base = make(family, seed=seed, n_agents=3) if family == "random" else make(family)
    sim = Simulator(base)
    kin = TeamKinematics(base, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE)
    state = [np.zeros((base.n_agents, NU)), *(np.ascontiguousarray(a) for a in (
        sim.state.q, sim.state.zeta, sim.state.q, sim.state.zeta, sim.state.x_O))]  # fmt: skip
    kin(*state, np.zeros((base.n_agents, 2)), np.zeros(5))
    pose = kin.pose_estimate.copy()
    # the first waypoint on robot 0's estimate, the last on robot 1's (others: as drawn)
    wps = np.array(base.waypoints, float)
    wps[0, :3] = pose[0, :3] + 0.1
    if len(wps) > 1:
        wps[-1, :3] = pose[1, :3] - 0.1
    scene = replace(base, waypoints=wps)
    kin = TeamKinematics(scene, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE)
    last = len(wps) - 1
    cases = [np.zeros((scene.n_agents, 2)), np.tile([last, 0.0], (scene.n_agents, 1))]
    cases.append(np.tile([last, 1.0], (scene.n_agents, 1)))  # done: nothing moves
    moved = 0
    for sequencers in cases:
        kin(*state, np.ascontiguousarray(sequencers), np.zeros(5))
        ref_seq, ref_wp, ref_twist = _reference(kin, scene, sequencers)
        assert np.array_equal(kin.sequencers, ref_seq)
        assert np.array_equal(kin.observation[:, WAYPOINT], ref_wp)
        assert np.abs(kin.observation[:, NAV] - ref_twist).max() < 1e-12
        moved += int((kin.sequencers != sequencers).any())
    assert moved >= 1  # the cases reach the passing branch


def _team_reference(scene, x_o: np.ndarray, team: np.ndarray, attitude: float) -> np.ndarray:
    """The team's rule on the true object, and Phi = |p_O - p_wp| + w |wrap(att_O - att_wp)|
    towards the waypoint before and after it moved, and the goal test."""
    wps = np.asarray(scene.waypoints, float)

    def potential(i: int) -> tuple[float, float]:
        d = x_o - wps[i]
        dist = float(np.linalg.norm(d[:3]))
        return dist + attitude * float(np.linalg.norm(wrap_angle(d[3:]))), dist

    index, done = int(team[0]), team[1] > 0
    before, dist = potential(index)
    near = not done and dist < WAYPOINT_TOLERANCE
    last = index + 1 >= len(wps)
    passed = near and not last
    index, done = index + passed, done or (near and last)
    d_goal = x_o - wps[-1]
    at_goal = (np.linalg.norm(d_goal[:3]) < scene.success_pos_tol) and (
        np.abs(wrap_angle(d_goal[3:])).max() < scene.success_att_tol
    )
    return np.array([index, done, before, potential(index)[0], passed, at_goal], float)


@pytest.mark.parametrize("family, seed", [("paper", 0), ("random", 4)])  # 3 waypoints each
def test_kernel_sequences_the_team_and_tests_the_goal_as_the_rule(family, seed):
    """The first waypoint and the goal moved next to the true object (within the
    tolerances: the team passes the first and is at the goal), and the scene as drawn
    (far from both); from the first waypoint, from the last and done."""
    base = make(family, seed=seed, n_agents=3) if family == "random" else make(family)
    sim = Simulator(base)
    x_o = np.ascontiguousarray(sim.state.x_O)
    state = [np.zeros((base.n_agents, NU)), *(np.ascontiguousarray(a) for a in (
        sim.state.q, sim.state.zeta, sim.state.q, sim.state.zeta)), x_o]  # fmt: skip
    wps = np.array(base.waypoints, float)
    wps[0] = x_o + np.r_[0.3, -0.2, 0.1, 0.4, -0.3, 2.9] * WAYPOINT_TOLERANCE / 2
    wps[-1] = x_o + np.r_[0.5 * base.success_pos_tol, 0.0, 0.0, 0.0, 0.0, 0.0]
    wps[-1, 5] += 0.5 * base.success_att_tol - 2 * np.pi  # wrapped: within the tolerance
    attitude = 0.7
    seen = np.zeros((2, 2))  # [passed, at goal] x [no, yes]
    for scene in (replace(base, waypoints=wps), base):
        kin = TeamKinematics(scene, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE)
        last = len(scene.waypoints) - 1
        for index, done in ((0, 0.0), (last, 0.0), (last, 1.0)):
            tests = (attitude, scene.success_pos_tol, scene.success_att_tol)
            team = np.array([index, done, *tests])
            kin(*state, np.zeros((scene.n_agents, 2)), team)
            rows = kin.team_rows()
            got = np.r_[rows[TEAM_SEQUENCER], rows[[POTENTIAL, POTENTIAL_AFTER, PASSED, AT_GOAL]]]
            ref = _team_reference(scene, x_o, team, attitude)
            assert np.abs(got - ref).max() < 1e-12
            seen[0, int(ref[4])] += 1
            seen[1, int(ref[5])] += 1
    assert seen.all()  # both outcomes of both tests are reached
