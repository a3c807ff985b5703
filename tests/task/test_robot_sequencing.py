"""Each robot's waypoint sequencer and navigation twist, computed inside the team kernel
(``uvms_env.task.team_kernel``), against an independent computation: the sequencing rule
written out in numpy on the kernel's own estimates, and the scene's own navigator
(``WaypointNavigator.casadi_function``, the waypoint's constants baked in)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uvms_env.dynamics import NU
from uvms_env.navigation.task_navigator import WAYPOINT_TOLERANCE, task_navigator
from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT, OBSERVATION_STRUCTURE
from uvms_env.scenarios import make
from uvms_env.sim import Simulator
from uvms_env.task.team_kernel import TeamKinematics

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
    kin(*state, np.zeros((base.n_agents, 2)))
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
        kin(*state, np.ascontiguousarray(sequencers))
        ref_seq, ref_wp, ref_twist = _reference(kin, scene, sequencers)
        assert np.array_equal(kin.sequencers, ref_seq)
        assert np.array_equal(kin.observation[:, WAYPOINT], ref_wp)
        assert np.abs(kin.observation[:, NAV] - ref_twist).max() < 1e-12
        moved += int((kin.sequencers != sequencers).any())
    assert moved >= 1  # the cases reach the passing branch
