"""Rimon-Koditschek navigation function on the position of the carried object.

The team is a ball of radius ``R`` (``team_radius``) centred at the object position
``p``; :class:`NavigationField` gives a reference velocity for ``p`` towards a goal
``p_d`` that keeps the ball clear of every obstacle (workspace ball deflated by ``R``,
vertical :class:`Cylinder` and :class:`Sphere` obstacles inflated by ``R``).  The math
(log-form numerics, the direction ``n(p) = -(p - p_d - gamma S / (2k))``, the speed law
``min(v_max, K_NF |p - p_d|)``, the conventions at the goal and outside the free space,
the choice of ``k``) is in docs/model.md, "Navigation function".

Units: metres, seconds, radians; attitudes are ZYX Euler angles ``(phi, theta, psi)``.

Dependencies: this package may import numpy and casadi only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from uvms_env.dynamics.spatial import wrap_angle, wrap_angle_sx

__all__ = [
    "Cylinder",
    "NavigationField",
    "Obstacle",
    "Sphere",
    "Workspace",
    "choose_k",
    "descend",
    "sample_free_points",
    "wrap_angle",
]

FloatArray = NDArray[np.float64]

#: Regularisation of norms, ``|x| := sqrt(|x|^2 + EPS^2)``; far below any physical length.
EPS = 1e-15


# The navigation field's defaults (paper eq8, eq9): the paper's exponent k, the speed
# gain K_NF [1/s] and the speed limit v_max [m/s] of the velocity reference.
PAPER_K = 6.0
NAV_GAIN = 0.5
NAV_MAX_SPEED = 0.25


def _check_finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _check_radius(name: str, value: float) -> float:
    value = _check_finite(name, value)
    if value < 0.0:
        raise ValueError(f"{name} must be non-negative, got {value}")
    return value


def _as_vector(name: str, value: ArrayLike, size: int) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array of shape ({size},)") from exc
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN/inf), got {arr}")
    return arr


def _as_points(name: str, value: ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (M, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN/inf)")
    return arr


@dataclass(frozen=True)
class Cylinder:
    """Vertical cylinder obstacle, infinite in z: its axis at (``x``, ``y``) in the
    horizontal plane [m], ``radius`` >= 0 [m]."""

    x: float
    y: float
    radius: float

    def __post_init__(self) -> None:
        # normalise to plain floats so instances compare and hash by value
        object.__setattr__(self, "x", _check_finite("Cylinder.x", self.x))
        object.__setattr__(self, "y", _check_finite("Cylinder.y", self.y))
        object.__setattr__(self, "radius", _check_radius("Cylinder.radius", self.radius))


@dataclass(frozen=True)
class Sphere:
    """Spherical obstacle: ``center`` [m], ``radius`` >= 0 [m]."""

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self) -> None:
        center = _as_vector("Sphere.center", self.center, 3)
        object.__setattr__(self, "center", tuple(float(c) for c in center))
        object.__setattr__(self, "radius", _check_radius("Sphere.radius", self.radius))


@dataclass(frozen=True)
class Workspace:
    """Ball that bounds the workspace: ``center`` [m], ``radius`` > 0 [m]."""

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self) -> None:
        center = _as_vector("Workspace.center", self.center, 3)
        object.__setattr__(self, "center", tuple(float(c) for c in center))
        radius = _check_radius("Workspace.radius", self.radius)
        if radius == 0.0:
            raise ValueError("Workspace.radius must be positive, got 0")
        object.__setattr__(self, "radius", radius)


Obstacle = Cylinder | Sphere


def _attitude_rate_ca(attitude: ca.SX, goal: Any, gain: Any, max_rate: Any) -> ca.SX:
    """Attitude law: ZYX Euler-angle rates ``clip(-gain wrap(attitude - goal), +-max_rate)``
    (goal, gain and saturation numbers or symbols)."""
    raw = -gain * wrap_angle_sx(attitude - goal)
    return ca.fmin(ca.fmax(raw, -max_rate), max_rate)


class NavigationField:
    """Rimon-Koditschek navigation function for the object position (docs/model.md).

    ``goal`` (3,): ``p_d`` [m], in the free space; the ``workspace`` ball is deflated and
    the ``obstacles`` inflated by ``team_radius``, the radius ``R`` [m] of the ball that
    encloses the object and the robots; ``k`` >= 1: the exponent; ``gain``: ``K_NF`` [1/s]
    of the speed law ``min(max_speed, gain * |p - p_d|)``, ``max_speed`` [m/s]. ValueError
    on negative radii, ``k < 1``, non-positive gain or speed, NaN/inf entries, a workspace
    not larger than the team, or a goal outside the free space."""

    def __init__(
        self,
        goal: ArrayLike,
        workspace: Workspace,
        obstacles: Sequence[Obstacle],
        team_radius: float,
        k: float = PAPER_K,
        gain: float = NAV_GAIN,
        max_speed: float = NAV_MAX_SPEED,
    ) -> None:
        self._goal = _as_vector("goal", goal, 3)
        if not isinstance(workspace, Workspace):
            raise TypeError(f"workspace must be a Workspace, got {type(workspace).__name__}")
        self._team_radius = _check_radius("team_radius", team_radius)
        self._k = _check_finite("k", k)
        if self._k < 1.0:
            raise ValueError(f"k must be >= 1, got {self._k}")
        self._gain = _check_finite("gain", gain)
        if self._gain <= 0.0:
            raise ValueError(f"gain must be positive, got {self._gain}")
        self._max_speed = _check_finite("max_speed", max_speed)
        if self._max_speed <= 0.0:
            raise ValueError(f"max_speed must be positive, got {self._max_speed}")
        obstacles = tuple(obstacles)
        for i, obs in enumerate(obstacles):
            if not isinstance(obs, (Cylinder, Sphere)):
                raise TypeError(
                    f"obstacle {i} must be a Cylinder or a Sphere, got {type(obs).__name__}"
                )
        self._workspace = workspace
        self._obstacles = obstacles

        self._ws_center = np.asarray(workspace.center, dtype=float)
        self._ws_radius = float(workspace.radius) - self._team_radius
        if self._ws_radius <= 0.0:
            raise ValueError(
                f"workspace radius ({workspace.radius}) must exceed team_radius "
                f"({self._team_radius})"
            )
        cyl = [o for o in obstacles if isinstance(o, Cylinder)]
        sph = [o for o in obstacles if isinstance(o, Sphere)]
        self._cyl_xy = np.array([[c.x, c.y] for c in cyl], dtype=float).reshape(-1, 2)
        self._cyl_r = np.array([c.radius for c in cyl], dtype=float) + self._team_radius
        self._sph_c = np.array([s.center for s in sph], dtype=float).reshape(-1, 3)
        self._sph_r = np.array([s.radius for s in sph], dtype=float) + self._team_radius

        goal_clearance = float(self.clearance_batch(self._goal[None, :])[0])
        if goal_clearance <= 0.0:
            raise ValueError(
                f"goal {self._goal.tolist()} is outside the free space "
                f"(clearance {goal_clearance:.3g} m with team_radius {self._team_radius})"
            )

    # ------------------------------------------------------------------ properties
    @property
    def goal(self) -> FloatArray:
        """Goal position ``p_d`` (copy), shape (3,)."""
        return self._goal.copy()

    @property
    def workspace(self) -> Workspace:
        """Bounding ball as given (not deflated)."""
        return self._workspace

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        """Obstacles as given (not inflated)."""
        return self._obstacles

    @property
    def team_radius(self) -> float:
        """Team radius ``R`` [m]."""
        return self._team_radius

    @property
    def k(self) -> float:
        """Navigation-function exponent."""
        return self._k

    @property
    def gain(self) -> float:
        """``K_NF`` [1/s]."""
        return self._gain

    @property
    def max_speed(self) -> float:
        """Speed saturation [m/s]."""
        return self._max_speed

    # ------------------------------------------------------------------ internals
    def _betas(self, pts: FloatArray) -> tuple[FloatArray, FloatArray]:
        """All factors ``beta_j`` (M, J) and their gradients (M, J, 3); j = 0 is the workspace."""
        m = pts.shape[0]
        d0 = pts - self._ws_center
        betas = [(self._ws_radius**2 - np.sum(d0 * d0, axis=1))[:, None]]
        grads = [(-2.0 * d0)[:, None, :]]
        if self._cyl_r.size:
            dxy = pts[:, None, :2] - self._cyl_xy[None, :, :]
            betas.append(np.sum(dxy * dxy, axis=2) - self._cyl_r**2)
            g = np.zeros((m, self._cyl_r.size, 3))
            g[:, :, :2] = 2.0 * dxy
            grads.append(g)
        if self._sph_r.size:
            ds = pts[:, None, :] - self._sph_c[None, :, :]
            betas.append(np.sum(ds * ds, axis=2) - self._sph_r**2)
            grads.append(2.0 * ds)
        return np.concatenate(betas, axis=1), np.concatenate(grads, axis=1)

    def _terms(
        self, pts: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Shared pieces: error e, gamma, betas, their gradients, S, free mask."""
        e = pts - self._goal
        gamma = np.sum(e * e, axis=1)
        betas, grads = self._betas(pts)
        free = np.all(betas > 0.0, axis=1)
        # Rows outside the free space get their own conventions; neutral betas there keep
        # the (discarded) free-space branch finite instead of dividing by <= 0.
        safe = np.where(free[:, None], betas, 1.0)
        s = np.sum(grads / safe[:, :, None], axis=1)
        return e, gamma, betas, grads, s, free

    @staticmethod
    def _recovery(betas: FloatArray, grads: FloatArray) -> FloatArray:
        """Unit direction back into the free space (zeros inside it)."""
        norms = np.sqrt(np.sum(grads * grads, axis=2) + EPS**2)
        unit = grads / norms[:, :, None]
        r = np.sum(np.where((betas <= 0.0)[:, :, None], unit, 0.0), axis=1)
        return r / np.sqrt(np.sum(r * r, axis=1) + EPS**2)[:, None]

    # ------------------------------------------------------------------ batch API
    def descent_direction_batch(self, points: ArrayLike) -> FloatArray:
        """Unit vector along ``-grad phi`` (zero at the goal), recovery direction outside."""
        pts = _as_points("points", points)
        e, gamma, betas, grads, s, free = self._terms(pts)
        n = -(e - gamma[:, None] * s / (2.0 * self._k))
        n = n / np.sqrt(np.sum(n * n, axis=1) + EPS**2)[:, None]
        return np.where(free[:, None], n, self._recovery(betas, grads))

    def clearance_batch(self, points: ArrayLike) -> FloatArray:
        """Signed clearance [m] of the team ball at each row of ``points`` (> 0 free)."""
        pts = _as_points("points", points)
        c = [self._ws_radius - np.linalg.norm(pts - self._ws_center, axis=1)]
        if self._cyl_r.size:
            dxy = pts[:, None, :2] - self._cyl_xy[None, :, :]
            c.append(np.min(np.linalg.norm(dxy, axis=2) - self._cyl_r, axis=1))
        if self._sph_r.size:
            ds = pts[:, None, :] - self._sph_c[None, :, :]
            c.append(np.min(np.linalg.norm(ds, axis=2) - self._sph_r, axis=1))
        return np.min(np.stack(c, axis=1), axis=1)

    # ------------------------------------------------------------------ CasADi
    def casadi_velocity(self, p: ca.SX) -> ca.SX:
        """Symbolic desired object velocity (3x1) at the object position ``p``, a 3x1
        ``SX`` (``scene_velocity``)."""
        cylinders = ca.DM(np.c_[self._cyl_xy, self._cyl_r, np.ones(self._cyl_r.size)])
        spheres = ca.DM(np.c_[self._sph_c, self._sph_r, np.ones(self._sph_r.size)])
        return scene_velocity(
            p,
            ca.DM(self._goal),
            ca.DM(np.append(self._ws_center, self._ws_radius)),
            ca.reshape(cylinders, self._cyl_r.size, 4),
            ca.reshape(spheres, self._sph_r.size, 5),
            self._k,
            self._gain,
            self._max_speed,
        )

    def casadi_function(self) -> ca.Function:
        """CasADi function ``nav_velocity``: ``p`` (3x1) -> ``v_d`` (3x1), SX-built."""
        p = ca.SX.sym("p", 3, 1)
        return ca.Function("nav_velocity", [p], [self.casadi_velocity(p)], ["p"], ["v_d"])


# ---------------------------------------------------------------------- k selection
def descend(
    field: NavigationField,
    starts: ArrayLike,
    step: float = 0.05,
    goal_tol: float = 0.3,
    max_iter: int = 4000,
    stall_window: int = 200,
) -> tuple[NDArray[np.bool_], FloatArray]:
    """Normalized gradient descent on ``log phi`` from many starts at once.

    Each step moves by ``min(step, clearance / 2, |p - p_d| / 2)`` along ``-grad phi``,
    so an iterate never leaves the free space.  A start is given up when it has not come
    within ``goal_tol`` of the goal after ``max_iter`` steps, or when it has moved less
    than ``step`` (net) over the last ``stall_window`` steps: with normalized steps an
    iterate at a spurious minimum keeps jumping back and forth across it, while a
    descending one moves about ``step`` per iteration (the field repels it from the
    boundary, so the clearance cap does not keep it slow for long).

    ``starts`` (M, 3): in the free space; ``step`` and ``goal_tol`` in m. Returns (reached:
    (M,) bool, whether each start reached the goal; the last iterates (M, 3))."""
    pts = _as_points("starts", starts).copy()
    if not step > 0.0 or not goal_tol > 0.0:
        raise ValueError("step and goal_tol must be positive")
    if stall_window < 1 or max_iter < 0:
        raise ValueError("stall_window must be >= 1 and max_iter >= 0")
    goal = field.goal
    reached = np.linalg.norm(pts - goal, axis=1) < goal_tol
    stuck = np.zeros_like(reached)
    snapshot = pts.copy()
    for it in range(1, max_iter + 1):
        active = ~(reached | stuck)
        if not np.any(active):
            break
        p = pts[active]
        direction = field.descent_direction_batch(p)
        dist = np.linalg.norm(p - goal, axis=1)
        h = np.minimum(step, np.minimum(0.5 * field.clearance_batch(p), 0.5 * dist))
        pts[active] = p + h[:, None] * direction
        reached[active] = np.linalg.norm(pts[active] - goal, axis=1) < goal_tol
        if it % stall_window == 0:
            moved = np.linalg.norm(pts - snapshot, axis=1)
            stuck |= ~reached & (moved < step)
            snapshot = pts.copy()
    return reached, pts


def sample_free_points(
    field: NavigationField,
    count: int,
    rng: np.random.Generator,
    min_clearance: float = 1e-3,
) -> FloatArray:
    """``count`` uniform samples (count, 3) of ``field``'s free space (rejection sampling
    in the workspace ball), none within ``min_clearance`` [m] of its boundary."""
    center = np.asarray(field.workspace.center, dtype=float)
    radius = field.workspace.radius - field.team_radius
    out: list[FloatArray] = []
    have = 0
    for _ in range(1000):
        if have >= count:
            break
        cand = rng.normal(size=(4 * count, 3))
        cand /= np.linalg.norm(cand, axis=1)[:, None]
        cand *= radius * rng.random(4 * count)[:, None] ** (1.0 / 3.0)
        cand += center
        cand = cand[field.clearance_batch(cand) > min_clearance]
        out.append(cand)
        have += cand.shape[0]
    if have < count:
        raise ValueError("free space is too small to sample")
    return np.concatenate(out, axis=0)[:count]


def choose_k(
    goal: ArrayLike,
    workspace: Workspace,
    obstacles: Sequence[Obstacle],
    team_radius: float,
    k_start: float = 4.0,
    factor: float = 1.5,
    k_max: float = 50.0,
    samples: int = 200,
    seed: int = 0,
) -> float:
    """Smallest ``k`` of the sequence ``k_start * factor**i`` without spurious minima.

    Rule: for each candidate ``k`` (increasing, capped at ``k_max``), run :func:`descend`
    from ``samples`` uniform free points (fixed ``seed``); return the first ``k`` for
    which every start reaches the goal.  This is an empirical stand-in for the
    conservative Rimon-Koditschek bound. The scene is as for :class:`NavigationField`;
    ``k_start`` >= 1, ``factor`` > 1. ValueError if no candidate up to ``k_max`` passes,
    or on invalid arguments."""
    if not factor > 1.0:
        raise ValueError(f"factor must be > 1, got {factor}")
    k = _check_finite("k_start", k_start)
    if k < 1.0:
        raise ValueError(f"k must be >= 1, got {k}")
    starts: FloatArray | None = None
    while True:
        field = NavigationField(goal, workspace, obstacles, team_radius, k=k)
        if starts is None:
            starts = sample_free_points(field, samples, np.random.default_rng(seed))
        reached, _ = descend(field, starts)
        if np.all(reached):
            return k
        if k >= k_max:
            raise ValueError(
                f"no k <= {k_max} removes the local minima ({np.sum(~reached)} of "
                f"{samples} starts fail at k = {k})"
            )
        k = min(k * factor, k_max)


def _select(c: ca.SX, a: ca.SX, b: ca.SX) -> ca.SX:
    """``a`` where ``c == 1``, ``b`` where ``c == 0``; exact when ``a`` and ``b`` are finite."""
    return c * a + (1.0 - c) * b


def scene_velocity(
    p: ca.SX,
    goal: ca.SX,
    workspace: ca.SX,
    cylinders: ca.SX,
    spheres: ca.SX,
    k: ca.SX,
    gain: ca.SX,
    max_speed: ca.SX,
) -> ca.SX:
    """The navigation velocity of ``NavigationField`` with the scene as arguments (SX
    symbols for a function shared by every scene, or numbers), branch-free: the one
    symbolic form of the formulas, which ``casadi_velocity`` calls with its own scene.

    ``p``, ``goal``: 3x1 object and goal positions; ``workspace`` 4x1 ``[c_ws; r_ws - R]``;
    ``cylinders`` n_cyl x 4, rows ``[x, y, r + R, present]``; ``spheres`` n_sph x 5, rows
    ``[cx, cy, cz, r + R, present]``; ``k``, ``gain``, ``max_speed``: the exponent,
    ``K_NF`` and ``v_max``. Returns the desired object velocity (3x1)."""
    e = p - goal
    gamma = ca.dot(e, e)
    d0 = p - workspace[0:3]
    betas: list[ca.SX] = [workspace[3] * workspace[3] - ca.dot(d0, d0)]
    grads: list[ca.SX] = [-2.0 * d0]
    for j in range(cylinders.size1()):
        dx = p[0] - cylinders[j, 0]
        dy = p[1] - cylinders[j, 1]
        present = cylinders[j, 3]
        b = dx * dx + dy * dy - cylinders[j, 2] * cylinders[j, 2]
        betas.append(_select(present, b, 1.0))
        grads.append(present * ca.vertcat(2.0 * dx, 2.0 * dy, 0.0))
    for j in range(spheres.size1()):
        ds = p - spheres[j, 0:3].T
        present = spheres[j, 4]
        b = ca.dot(ds, ds) - spheres[j, 3] * spheres[j, 3]
        betas.append(_select(present, b, 1.0))
        grads.append(present * (2.0 * ds))

    free = ca.SX(1)
    for b in betas:
        free = free * (b > 0.0)
    s = ca.SX.zeros(3, 1)
    rec = ca.SX.zeros(3, 1)
    for b, g in zip(betas, grads, strict=True):
        # the neutral beta (1) outside the free space keeps the unused branch finite
        s += g / _select(free, b, 1.0)
        rec += (b <= 0.0) * (g / ca.sqrt(ca.dot(g, g) + EPS**2))
    rec = rec / ca.sqrt(ca.dot(rec, rec) + EPS**2)

    n = -(e - gamma * s / (2.0 * k))
    speed = ca.fmin(max_speed, gain * ca.sqrt(gamma + EPS**2))
    v = n * (speed / ca.sqrt(ca.dot(n, n) + EPS**2))
    return _select(free, v, max_speed * rec)
