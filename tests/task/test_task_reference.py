"""The task's reward and constraint values against a plain reference written here from
the documented formulas (``uvms_env.task.reward``, ``uvms_env.task.constraints``), fed only
the global state (``env.state()``), the actions and the limits of ``parameters.toml``.

The single-vs-vector tests drive the same ``EnvCore`` and ``Task`` on both sides, so they
cannot catch a wrong rule; this one recomputes the rules independently: the reward terms
(progress as a potential difference towards the team's waypoint, the waypoint bonus, the
violation and effort penalties, their sum) and the constraint kinds that follow from the
state alone (input, joint limit, joint speed, vehicle speed, representation). The
geometric kinds (manipulability, collision, workspace) need the kinematics and are checked
elsewhere (tests/physics/test_pinocchio_crosscheck.py, tests/env/test_env.py); here they only enter
the violation count."""

from __future__ import annotations

import numpy as np

import uvms_env
from uvms_env.dynamics import NQ, NU
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.infos import reward_terms
from uvms_env.env.options import state_structure
from uvms_env.task.constraints import CONSTRAINTS, REPRESENTATION_MARGIN, SAFETY_CONSTRAINTS
from uvms_env.task.reward import RewardWeights

STEPS = 40
STATE_TOL = 2e-5  # env.state() is float32; the env's own values are float64


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def potential(pose: np.ndarray, waypoint: np.ndarray, w: RewardWeights) -> float:
    att = wrap(pose[3:] - waypoint[3:])
    return float(np.linalg.norm(pose[:3] - waypoint[:3]) + w.attitude * np.linalg.norm(att))


def reference_constraints(state: np.ndarray, action: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """The state-only kinds per robot, g <= 0 holds (the module docstring's table)."""
    lim = default_model().params.limits
    st = state_structure(n)
    q = state[st["q"]].reshape(n, NQ).astype(float)
    zeta = state[st["zeta"]].reshape(n, NQ).astype(float)
    theta_o = float(state[st["object_pose"]][4])
    bound = np.pi / 2 - REPRESENTATION_MARGIN
    return {
        "input": np.abs(action).max(axis=1) - 1.0,
        "joint_limit": np.abs(q[:, 6:]).max(axis=1) - lim.joint_position,
        "joint_speed": np.abs(zeta[:, 6:]).max(axis=1) - lim.joint_speed,
        "vehicle_speed": np.maximum(
            np.abs(zeta[:, :3]).max(axis=1) / lim.vehicle_linear_speed,
            np.abs(zeta[:, 3:6]).max(axis=1) / lim.vehicle_angular_speed,
        )
        - 1.0,
        "representation": np.maximum(np.abs(q[:, 4]), abs(theta_o)) - bound,
    }


SAFETY = [CONSTRAINTS.index(k) for k in SAFETY_CONSTRAINTS]


def test_reward_and_state_constraints_match_the_documented_formulas():
    env = uvms_env.parallel_env("random", n_agents=3, current="mild", mismatch=0.1)
    agents = env.possible_agents
    n, w = len(agents), RewardWeights()
    st = state_structure(n)
    env.reset(seed=12)
    rng = np.random.default_rng(3)
    state = env.state()
    seen = {kind: 0 for kind in CONSTRAINTS}
    for t in range(STEPS):
        # a pull beyond the saturation now and then: input violations to count
        action = rng.uniform(-1.2, 1.2, (n, NU)).astype(np.float32)
        _, rewards, terms, truncs, infos = env.step(dict(zip(agents, action, strict=True)))
        after = env.state()
        g = np.array([[infos[a][f"constraint_{k}"] for k in CONSTRAINTS] for a in agents])
        ref = reference_constraints(after, action, n)
        for kind, values in ref.items():
            k = CONSTRAINTS.index(kind)
            np.testing.assert_allclose(g[:, k], values, rtol=0, atol=STATE_TOL, err_msg=kind)
        # the reward, term by term, from the states before and after
        waypoint_before = state[st["waypoint"]]
        pose_after = after[st["object_pose"]].astype(float)
        progress = w.progress * (
            potential(state[st["object_pose"]].astype(float), waypoint_before, w)
            - potential(pose_after, waypoint_before, w)
        )
        passed = not np.array_equal(after[st["waypoint"]], waypoint_before)
        # the safety kinds: the input is clipped before the simulator, reported, not counted
        violated = int((g[:, SAFETY] > 0).sum())
        clipped = np.clip(action.astype(float), -1, 1)
        reference = {
            "progress": progress,
            "waypoint": w.waypoint * passed,
            "success": 0.0,
            "violation": -w.violation * violated / n,
            "effort": -w.effort * float((clipped**2).mean()),
        }
        got = reward_terms(infos[agents[0]])
        for name, value in reference.items():
            assert abs(got[name] - value) < 1e-3, (t, name, got[name], value)
        assert abs(rewards[agents[0]] - sum(got.values())) < 1e-9
        assert all(r == rewards[agents[0]] for r in rewards.values())  # shared
        for kind in CONSTRAINTS:
            seen[kind] += int((g[:, CONSTRAINTS.index(kind)] > 0).any())
        state = after
        if any(terms.values()) or any(truncs.values()):
            break
    assert seen["input"] > 0  # the saturation was exceeded: reported, and left out of the term
