"""An independent numpy writing of the ``uvms-v1`` features, for the tests: the package
computes them from one CasADi expression (``uvms_env.robot.priors.featurize_sx``, compiled
for ``featurize`` and inside the batched kernels); this reference is array code written
from the same specification (docs/environment.md, "Priors"), so that a mistake in the
expression shows as a disagreement."""

from __future__ import annotations

import numpy as np

from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.robot.observation import OBSERVATION_STRUCTURE
from uvms_env.robot.priors import OBS_DIM, OBSTACLE_RANGE


def featurize_reference(obs: np.ndarray) -> np.ndarray:
    """(..., 79) observations -> (..., 76) float32 ``uvms-v1`` features, in numpy."""
    o = np.asarray(obs, dtype=np.float64)
    if o.shape[-1] != OBS_DIM:
        raise ValueError(f"uvms-v1 features need {OBS_DIM}-number observations, got {o.shape}")
    f = {name: o[..., sl] for name, sl in OBSERVATION_STRUCTURE.items()}
    q, pose, twist = f["q"], f["object_pose"], f["object_twist"]
    psi = q[..., 5]  # vehicle yaw
    c, s = np.cos(psi), np.sin(psi)

    def yaw_frame(v: np.ndarray) -> np.ndarray:  # (..., 3) NED -> heading frame
        return np.stack(
            [c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], -1
        )

    wp, goal, nav = f["waypoint"], f["goal"], f["nav_velocity"]
    obst = f["obstacles"].reshape(*o.shape[:-1], 3, 5)
    present = (obst[..., 3] > 0).astype(np.float64)
    dxy = obst[..., :2]
    dist = np.linalg.norm(dxy, axis=-1, keepdims=True)
    dxy = dxy * np.minimum(1.0, OBSTACLE_RANGE / np.maximum(dist, 1e-9))
    cc, ss = c[..., None], s[..., None]
    ob_body = np.stack(
        [cc * dxy[..., 0] + ss * dxy[..., 1], -ss * dxy[..., 0] + cc * dxy[..., 1]], -1
    )
    obstacles = np.concatenate(
        [ob_body * present[..., None], obst[..., 2:5] * present[..., None]], -1
    ).reshape(*o.shape[:-1], 15)
    parts = [
        q[..., 2:5],  # vehicle depth, roll, pitch
        q[..., 6:10],  # joint angles
        f["zeta"],  # body twist and joint rates
        pose[..., 2:5],  # object depth, roll, pitch
        wrap_angle(pose[..., 5:6] - psi[..., None]),  # object yaw relative to the vehicle's
        yaw_frame(twist[..., :3]),
        yaw_frame(twist[..., 3:]),
        yaw_frame(wp[..., :3] - pose[..., :3]),
        wrap_angle(wp[..., 3:] - pose[..., 3:]),
        yaw_frame(goal[..., :3] - pose[..., :3]),
        wrap_angle(goal[..., 3:] - pose[..., 3:]),
        yaw_frame(nav[..., :3]),
        nav[..., 3:],
        obstacles,
        yaw_frame(q[..., 0:3] - pose[..., :3]),
        f["load_share"],
        f["grasp_offset"],
        f["grasp_rotation"],
    ]
    return np.concatenate(parts, -1).astype(np.float32)
