"""The safety filter's workspace rows: how far the robot's own bodies and the object reach
outside the workspace ball, and their gradients, at the nodes of the plan.

The same balls as the environment's ``workspace`` constraint (``uvms_env.task.constraints``),
computed from the robot's own model state: its bodies from its configuration, the object
from its grasp (``LocalModel.object_state``, its own estimate of the shared object). Two
values per node, each the largest excess of a group of balls (its gradient is the largest
ball's, re-chosen at every linearization): the robot's own bodies, and the object. The
object is shared, so every filter of the team keeps it inside on its own. Only the
safety filter uses these rows (docs/safety-filter.md, "Workspace").

May import: numpy, casadi, ``uvms_env.dynamics`` and this package.
"""

from __future__ import annotations

from functools import cache

import casadi as cs
import numpy as np

from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.local_model import NX, build_local_model
from uvms_env.dynamics.payload import object_key, object_tag
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import default_model

NW_ROWS = 2  # per node: own bodies, object


def _barrier(balls: list[tuple[cs.SX, float]], q: cs.SX, q_dot: cs.SX, ws: cs.SX, rate: cs.SX):
    """Largest r = d/dt h + rate (h + margin) over the balls (h: how far the ball reaches
    outside the workspace ball ws = [c; R; margin]) and the largest h."""
    out, worst = None, None
    for centre, radius in balls:
        d = centre - ws[:3]
        dist = cs.sqrt(cs.dot(d, d) + 1e-12)
        h = dist + radius - ws[3]
        h_dot = cs.dot(d, cs.jtimes(centre, q, q_dot)) / dist
        r = h_dot + rate * (h + ws[4])
        out = r if out is None else cs.fmax(out, r)
        worst = h if worst is None else cs.fmax(worst, h)
    return out, worst


def object_points(shape: str, size: float) -> np.ndarray:
    """The object's segment end points in its own frame, each once (K, 3)."""
    points = np.array([p for seg in ObjectModel(shape, size).segments for p in seg])
    return np.unique(np.round(points, 12), axis=0)


@cache
def workspace_function(shape: str, size: float) -> cs.Function:
    """(x, theta, ws (6)) -> (r (2), dr/dx (2 x NX), h (2)) for the own bodies and the
    object: r = d/dt h + rate (h + margin), the largest over the group's balls, and h,
    the largest excess (compiled, disk-cached). ``ws``: centre, radius, margin, rate.
    ``size``: the object's size or key (``uvms_env.dynamics.payload.object_key``)."""
    uvms = default_model()
    prm = uvms.params
    model = build_local_model(uvms, ObjectModel(shape, size))
    x, theta = cs.SX.sym("x", NX), cs.SX.sym("theta", model.theta_size)
    ws = cs.SX.sym("ws", 6)  # centre, radius, margin, rate
    q = x[: NX // 2]
    q_dot = uvms.qdot_map(q) @ x[NX // 2 :]
    pts = uvms.body_points(q)
    own = [(pts[:, 0], prm.vehicle.bounding_radius)]
    own += [(pts[:, k], prm.arm.tube_radius) for k in range(1, pts.shape[1])]
    x_o, _ = model.object_state(x, theta)
    rot = rot_zyx(x_o[3:])
    obj = [(x_o[:3] + rot @ cs.DM(p), prm.object.tube_radius) for p in object_points(shape, size)]
    r_own, h_own = _barrier(own, q, q_dot, ws, ws[5])
    r_obj, h_obj = _barrier(obj, q, q_dot, ws, ws[5])
    r, h = cs.vertcat(r_own, r_obj), cs.vertcat(h_own, h_obj)
    tag = f"{shape}_{object_tag(object_key(shape, size))}"
    fn = cs.Function(
        f"filter_workspace_{tag}", [x, theta, ws], [r, cs.jacobian(r, x), h], {"cse": True}
    )
    return compile_function(fn)


class WorkspaceRows:
    """The workspace rows of the filter's QP (``RTISolver(extra=...)``), on node 1 only:
    per group (own bodies, object) the linearized barrier r = d/dt h + ``rate`` (h +
    ``margin``) <= 0, normalized by ``scale`` [m/s], soft with the penalties ``l1``,
    ``l2`` per normalized unit, like the expert's rows.

    Why node 1 only: r is a speed, one period from the inputs, and the vehicles' thrust
    changes it by a few cm/s per period; rows on later nodes asked the backup tail for
    what it cannot do, the tail saturated, and its linear prediction (the next period's
    linearization point) drifted far from the truth
    (docs/notes/2026-11-23-safety-filter-tuning.md)."""

    count = NW_ROWS

    def __init__(
        self,
        shape: str,
        size: float,
        theta: np.ndarray,
        workspace: tuple[np.ndarray, float],
        margin: float,
        rate: float,
        scale: float,
        l1: float,
        l2: float,
    ) -> None:
        if not (scale > 0 and rate > 0 and margin >= 0 and l1 >= 0 and l2 > 0):
            raise ValueError("workspace rows need scale, rate, l2 > 0 and margin, l1 >= 0")
        self._call = BufferCall(workspace_function(shape, size))
        self._theta = np.ascontiguousarray(theta, dtype=float)
        centre, radius = workspace
        self._ws = np.array([*np.asarray(centre, float), float(radius), margin, rate])
        self._x = np.zeros(NX)
        self.scale = float(scale)
        self.l1 = np.full(self.count, float(l1))
        self.l2 = np.full(self.count, float(l2))
        self._lower = np.full(self.count, -np.inf)
        # the filter's rate-offset estimate e (``LocalController.rate_offset``, shared):
        # the rows apply to zeta_1 + e, like the expert's speed rows
        self.zeta_offset = np.zeros(NX // 2)
        self.barrier = np.zeros(NW_ROWS)  # r at the plan's node 1 before the step [m/s]
        self.excess = np.zeros(NW_ROWS)  # h there [m]

    def values_at(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(r [m/s], h [m]) of the two groups at the model state x (copies)."""
        self._x[:] = x
        r_t, _, h_t = self._call(self._x, self._theta, self._ws)
        return r_t[0].copy(), h_t[0].copy()

    def rows(
        self, xbar: np.ndarray, g: np.ndarray, e: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(C (2 x 8N), lower, upper) around the plan ``xbar`` (N+1 x NX) with the
        condensed dynamics dx_1..dx_N = ``g`` da + ``e`` (only dx_1 is used)."""
        self._x[:] = xbar[1]
        r_t, jac, h_t = self._call(self._x, self._theta, self._ws)
        r = r_t[0]  # (1, 2): CasADi's column (2 x 1) as numpy reads it
        self.barrier[:], self.excess[:] = r, h_t[0]
        grad = jac.T  # (2, NX): numpy reads CasADi's column-major (2 x NX) transposed
        c = grad @ g[:NX] / self.scale
        upper = -(r + grad @ e[:NX] + grad[:, NX // 2 :] @ self.zeta_offset) / self.scale
        return c, self._lower, upper
