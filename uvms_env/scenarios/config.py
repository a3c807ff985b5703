"""The scenario: one typed, validated description of a cooperative transport task."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uvms_env.dynamics.payload import object_key
from uvms_env.dynamics.spatial import SINGULARITY_MARGIN
from uvms_env.models import load_parameters
from uvms_env.navigation import Cylinder, Sphere, Workspace
from uvms_env.scenarios.overrides import CURRENT_PRESETS, SCENARIO_FIELDS, SCENARIO_OVERRIDES

__all__ = ["CURRENT_PRESETS", "Scenario", "obstacle_distance", "validate"]


@dataclass(frozen=True, eq=False)
class Scenario:
    """Everything that defines an episode's world; robots know all of it a priori except
    the truth-model perturbations (``mismatch``), the current and the sensor noise.

    Geometry: robot i grasps the object at ``grasp_offsets[i]`` (object frame, m) with the
    end-effector rotation ``grasp_rotations[i]`` relative to the object frame. Its start
    configuration ``initial_q[i]`` satisfies the grasp exactly at ``object_start``.
    """

    name: str
    n_agents: int
    object_shape: str
    # the object's size (m): a ring's radius, a bar's length (0: the parameter file's bar;
    # canonical, ``uvms_env.dynamics.payload.object_size``)
    object_size: float
    grasp_offsets: np.ndarray  # (N, 3)
    grasp_rotations: np.ndarray  # (N, 3, 3)
    load_shares: np.ndarray  # (N,)
    object_start: np.ndarray  # (6,) [x y z phi theta psi]
    waypoints: np.ndarray  # (K, 6)
    obstacles: tuple[Cylinder | Sphere, ...]
    workspace: Workspace
    initial_q: np.ndarray  # (N, 10)
    robot_radius: float  # r_bar: ball around an end effector holding its whole UVMS
    team_radius: float  # R: ball around the object holding the whole team
    current: str = "none"
    damping_scale: float = 1.0
    # relative perturbation of the truth model: hydrodynamic coefficients by up to
    # mismatch, weighed quantities (masses, displaced volumes) by up to mismatch / 10
    mismatch: float = 0.0
    sensor_noise: float = 0.0  # scale of the sensor-noise model (0: perfect sensing)
    seed: int | None = None
    period: float = 0.12  # control period h [s]
    substeps: int = 8  # RK4 substeps per control period
    max_steps: int = 2000
    success_pos_tol: float = 0.15  # m, final waypoint
    success_att_tol: float = 0.1  # rad, final waypoint
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        validate(self)

    @property
    def object_key(self) -> float:
        """The object as one number, as the compiled functions, the priors and the
        datasets name it (``uvms_env.dynamics.payload.object_key``): the ring's radius; 0
        for the parameter file's bar, minus the length for another bar."""
        return object_key(self.object_shape, self.object_size)


def _shape(name: str, arr: np.ndarray, shape: tuple[int, ...]) -> None:
    if np.shape(arr) != shape:
        raise ValueError(f"scenario {name} must have shape {shape}, got {np.shape(arr)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"scenario {name} contains NaN or inf")


def obstacle_distance(points: np.ndarray, obstacle: Cylinder | Sphere) -> np.ndarray:
    """Signed distance of points (M,3) to an obstacle's surface (>0 outside)."""
    points = np.atleast_2d(points)
    if isinstance(obstacle, Cylinder):
        d = np.hypot(points[:, 0] - obstacle.x, points[:, 1] - obstacle.y)
    else:
        d = np.linalg.norm(points - np.asarray(obstacle.center), axis=1)
    return d - obstacle.radius


def validate(s: Scenario) -> None:
    """Raise ValueError naming the first inconsistency of the scenario (TypeError for a
    wrongly typed overridable field, e.g. ``sensor_noise="0.1"``; NaN and inf are values
    out of range)."""
    n = s.n_agents
    if not isinstance(n, int | np.integer) or n < 2:
        raise ValueError(f"n_agents must be an integer >= 2, got {n!r}")
    if s.object_shape not in ("bar", "ring"):
        raise ValueError(f"object_shape must be 'bar' or 'ring', got {s.object_shape!r}")
    size = s.object_size
    if not (isinstance(size, float | int | np.floating) and np.isfinite(size) and size >= 0):
        raise ValueError(f"object_size must be a finite float >= 0, got {size!r}")
    if s.object_shape == "ring" and size == 0:
        raise ValueError("object_size must be > 0 for a ring")
    _shape("grasp_offsets", s.grasp_offsets, (n, 3))
    _shape("grasp_rotations", s.grasp_rotations, (n, 3, 3))
    _shape("load_shares", s.load_shares, (n,))
    _shape("object_start", s.object_start, (6,))
    _shape("initial_q", s.initial_q, (n, 10))
    if s.waypoints.ndim != 2 or s.waypoints.shape[1] != 6 or len(s.waypoints) == 0:
        raise ValueError(f"waypoints must have shape (K, 6), K >= 1; got {s.waypoints.shape}")
    for r in s.grasp_rotations:
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-8) or np.linalg.det(r) < 0:
            raise ValueError("grasp_rotations must be proper rotation matrices")
    if np.any(s.load_shares <= 0) or np.any(s.load_shares >= 1):
        raise ValueError(f"load_shares must lie in (0, 1), got {s.load_shares}")
    if abs(float(np.sum(s.load_shares)) - 1.0) > 1e-9:
        raise ValueError(f"load_shares must sum to 1, got sum {np.sum(s.load_shares):.6g}")
    d = np.linalg.norm(s.grasp_offsets[:, None] - s.grasp_offsets[None], axis=-1)
    d[np.diag_indices(n)] = np.inf
    if d.min() < 2 * s.robot_radius - 1e-9:
        i, j = np.unravel_index(np.argmin(d), d.shape)
        raise ValueError(
            f"grasp points {i} and {j} are too close: {d.min():.3f} m apart, the robots' "
            f"bounding spheres need >= 2 * robot_radius = {2 * s.robot_radius:.3f} m"
        )
    for name in SCENARIO_FIELDS:  # the overridable fields: one schema (overrides.py)
        SCENARIO_OVERRIDES[name].check(name, getattr(s, name))
    if not (np.isfinite(s.period) and s.period > 0):
        raise ValueError(f"period must be a finite float > 0, got {s.period!r}")
    if abs(s.object_start[4]) >= np.pi / 2 - SINGULARITY_MARGIN:
        raise ValueError("object_start pitch is too close to the Euler singularity |theta| = pi/2")
    for k, wp in enumerate(np.vstack([s.object_start[None], s.waypoints])):
        what = "object_start" if k == 0 else f"waypoint {k - 1}"
        for m, obs in enumerate(s.obstacles):
            clearance = float(obstacle_distance(wp[:3], obs)[0]) - s.team_radius
            if clearance < 0:
                raise ValueError(
                    f"{what} at {np.round(wp[:3], 3).tolist()} is inside obstacle {m} inflated "
                    f"by the team radius {s.team_radius:.2f} m (clearance {clearance:.2f} m)"
                )
        inside = s.workspace.radius - np.linalg.norm(wp[:3] - np.asarray(s.workspace.center))
        if inside < s.team_radius:
            raise ValueError(f"{what} is outside the workspace shrunk by the team radius")
    params = load_parameters()
    lim = params.limits.joint_position
    if np.any(np.abs(s.initial_q[:, 6:]) > lim):
        raise ValueError(f"initial_q violates the joint limits |q_m| <= {lim} rad")
