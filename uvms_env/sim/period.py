"""The control period's error control and physical envelope, written once over an array
namespace ``xp``: the single ``Simulator`` runs it on one environment (K = 1), the
``BatchedSimulator`` on K (numpy), and the CUDA kernel's in-thread refinement
(``uvms_env.vector.kernels.Refinement``, built by ``uvms_env.vector.kernel_list``) is this
routine written out in C with these constants.

The period step itself (one compiled call: RK4 substeps, the projection onto the grasp
manifold, the drift before it and the grasp error after it) is injected as
``evaluate(ids, x0, h) -> (x_next, drift, error)``. A refused part of a period is
integrated again as two halves, down to 1/2**MAX_REFINEMENTS of a period (the rule and
the tolerances: docs/model.md, "Error control", "Divergence"): ``INACCURATE`` or
``ENVELOPE``. A refused environment keeps its state: that is the caller's part.

Layout: arrays (element, K), the environment index innermost, as the batched kernels read
them (the single simulator passes (element, 1) views of its vectors).

May import: numpy and ``uvms_env.dynamics`` (the state's layout); the array namespace
itself is a parameter (numpy, or CuPy).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from uvms_env.dynamics import NQ

# Error control (docs/model.md). Every period ends with a projection onto the grasp
# manifold inside the compiled step; how far the integrated state had drifted from it
# before (pose and twist residuals) is the accuracy check. A period whose drift exceeds
# these bounds is integrated again as two halves, recursively.
DRIFT_TOL_POSE = 1e-5  # m and rad
DRIFT_TOL_TWIST = 1e-4  # m/s and rad/s
MAX_REFINEMENTS = 4  # halvings: down to 1/16 of a period (128 substeps at the default 8)
# What the simulator promises at the end of every period (README): the grasp pose error
# after the projection. One Newton step from an accepted drift lands at ~1e-9 or below.
GRASP_TOL = 1e-6  # m and rad
# Single precision (the batched env's fast mode) resolves a position of 10-50 m to 1-4 um:
# it cannot meet 1e-6 after a projection, and with the float64 tolerances a float32 period
# was refused as "drifted" in half the episodes of random N = 2 and nearly every one of
# N = 6 bars under exploration noise (float64: none and 1 of 16 in 1,500 periods). Ten
# times the tolerances gave float32 the float64 rate.
FLOAT32_TOLERANCE_SCALE = 10.0
# The physical envelope: no input the saturations admit drives a UVMS or the object near
# these speeds with the model's damping (docs/model.md, "Divergence"). A state beyond them
# means the model was driven out of its validity (e.g. damping_scale=0): refused as diverged.
SPEED_LIMITS = {"linear": 5.0, "angular": 10.0, "joint": 20.0}  # m/s, rad/s, rad/s
# The verdict on an environment's period.
OK, INACCURATE, ENVELOPE = 0, 1, 2

# (ids, x0, h) -> (x_next, drift, error): the compiled period part of length h from x0
# (nx, m) for environments ids (None: every one, x0 the whole state). Outputs may carry
# padding columns past m. A refined part's x_next must outlive later calls (the first
# call's may be the caller's own buffer); drift and error are read before the next call.
Evaluate = Callable[[Any, Any, float], tuple[Any, Any, Any]]


def tolerances(real: Any = np.float64) -> tuple[float, float, float]:
    """(pose drift, twist drift, grasp error) tolerances of the period's error control in
    the precision ``real`` (numpy's float32 or float64)."""
    scale = FLOAT32_TOLERANCE_SCALE if np.dtype(real) == np.float32 else 1.0
    return DRIFT_TOL_POSE * scale, DRIFT_TOL_TWIST * scale, GRASP_TOL * scale


def speed_limits(n: int) -> np.ndarray:
    """(20 N + 12,) per state entry: the envelope's speed on the velocities (the robots'
    zeta, the object's twist), +inf on the positions (their finiteness is the error
    control's test)."""
    lin, ang, joint = (SPEED_LIMITS[k] for k in ("linear", "angular", "joint"))
    zeta = np.tile(np.r_[[lin] * 3, [ang] * 3, [joint] * 4], n)
    return np.r_[[np.inf] * (NQ * n), zeta, [np.inf] * 6, [lin] * 3, [ang] * 3]


def envelope_excess(x: np.ndarray, n: int) -> tuple[str, float]:
    """For one flat state (host) beyond the envelope: the first kind of speed beyond its
    limit and that speed (for the message; the test is ``PeriodControl.verdict``)."""
    zeta = np.abs(x[NQ * n : 2 * NQ * n]).reshape(n, NQ)
    v_o = np.abs(x[2 * NQ * n + 6 :])
    speeds = {
        "linear": max(zeta[:, :3].max(), v_o[:3].max()),
        "angular": max(zeta[:, 3:6].max(), v_o[3:].max()),
        "joint": zeta[:, 6:].max(),
    }
    for kind, value in speeds.items():
        if not value <= SPEED_LIMITS[kind]:
            return kind, float(value)
    return "", 0.0


class PeriodControl:
    """The error control and envelope of the period step of ``n`` robots, over arrays of
    ``xp`` in the precision ``real`` (module docstring).

    The refinement reads which environments a part refused (on a GPU, a host read per
    part): the CUDA backend runs it inside its kernel instead (``Refinement``) and takes
    ``verdict`` from here."""

    def __init__(self, n: int, xp: Any = np, real: Any = np.float64) -> None:
        self.xp = xp
        self._real = real
        # the bounds of one column: |drift| (12 per robot: pose, then twist residuals),
        # |grasp error| (6 per robot), |state| (finite: at most the largest float), in the
        # arrays' own precision as the kernel compares them (float32: 1e-5 rounded)
        pose, twist, grasp = tolerances(real)
        drift = np.tile(np.r_[[pose] * 6, [twist] * 6], n)
        big = np.finfo(real).max
        bounds = np.r_[drift, [grasp] * (6 * n), [big] * (2 * NQ * n + 12)]
        self._bounds = xp.asarray(bounds[:, None], real)
        self._drift_rows, self._state_row = 12 * n, 18 * n
        self._limits = xp.asarray(speed_limits(n)[:, None], real)
        self._scratch = self._columns(1)
        # the verdicts as 0-d int8 arrays of xp (cheaper in ``where`` than scalars)
        self._codes = tuple(xp.asarray(np.int8(c)) for c in (OK, INACCURATE, ENVELOPE))

    def _columns(self, m: int) -> tuple[Any, ...]:
        """A scratch array of m columns for the bounds' rows, and its drift, error and
        state parts (views, made once per shape: slicing costs on the hot path)."""
        a = self.xp.zeros((self._bounds.shape[0], m), self._real)
        d = self._drift_rows
        return a, a[:d], a[d : self._state_row], a[self._state_row :]

    def accurate(self, drift: Any, error: Any, x_next: Any) -> Any:
        """Per environment (column): drift, grasp error and state pass. NaN compares
        False: a non-finite residual or state is inaccurate."""
        xp = self.xp
        if self._scratch[0].shape[1] != x_next.shape[1]:
            self._scratch = self._columns(x_next.shape[1])
        a, a_drift, a_error, a_state = self._scratch  # one comparison, one reduction
        xp.abs(drift, out=a_drift)
        xp.abs(error, out=a_error)
        xp.abs(x_next, out=a_state)
        return (a <= self._bounds).all(axis=0)

    def verdict(self, ok: Any, x_next: Any) -> Any:
        """(m,) int8: ``OK``, ``INACCURATE`` where not ``ok``, ``ENVELOPE`` where an
        accurate period ends beyond the physical envelope."""
        xp = self.xp
        within = (xp.abs(x_next) <= self._limits).all(axis=0)
        ok_code, inaccurate, envelope = self._codes
        return xp.where(ok, xp.where(within, ok_code, envelope), inaccurate)

    def integrate(self, evaluate: Evaluate, x0: Any, h: float, m: int) -> tuple[Any, Any, int]:
        """The period of length ``h`` of the first ``m`` environments of ``x0``: one call for
        all, then the refused ones in halves. -> (x_next (nx, m), ok (m,), how many were
        refined). A refused environment's x_next is the start of the part that failed."""
        x_next, ok = self._evaluate(evaluate, None, x0, h, m)
        if bool(ok.all()):
            return x_next, ok, 0
        bad = self.xp.flatnonzero(~ok)
        x_next[:, bad], ok[bad] = self.refine(evaluate, bad, x0[:, bad], h)
        return x_next, ok, len(bad)

    def refine(self, evaluate: Evaluate, ids: Any, x0: Any, h: float) -> tuple[Any, Any]:
        """The periods of environments ``ids`` from ``x0`` that their one call refused,
        integrated again in halves (what ``integrate`` does after that call; a caller that
        makes the first call itself comes here only when it fails). -> (x_end, ok)."""
        return self._halves(evaluate, ids, x0, h, 1)

    def _evaluate(self, evaluate: Evaluate, ids: Any, x0: Any, h: float, m: int) -> tuple[Any, Any]:
        x_next, drift, error = evaluate(ids, x0, h)
        return x_next[:, :m], self.accurate(drift, error, x_next)[:m]

    def _halves(
        self, evaluate: Evaluate, ids: Any, x0: Any, h: float, level: int
    ) -> tuple[Any, Any]:
        """Part ``h`` of environments ``ids`` from ``x0`` as two halves, ``level`` halvings
        deep; one refused in the first half goes no further. -> (x_end, ok)."""
        x_mid, ok = self._part(evaluate, ids, x0, h / 2, level)
        if bool(ok.all()):
            return self._part(evaluate, ids, x_mid, h / 2, level)
        go = self.xp.flatnonzero(ok)
        if len(go):
            x_mid[:, go], ok[go] = self._part(evaluate, ids[go], x_mid[:, go], h / 2, level)
        return x_mid, ok

    def _part(self, evaluate: Evaluate, ids: Any, x0: Any, h: float, level: int) -> tuple[Any, Any]:
        """One part: accepted, halved again, or (``MAX_REFINEMENTS`` deep) refused, its
        x_end then its start. -> (x_end, ok)."""
        x_end, ok = self._evaluate(evaluate, ids, x0, h, len(ids))
        if bool(ok.all()):
            return x_end, ok
        bad = self.xp.flatnonzero(~ok)
        if level >= MAX_REFINEMENTS:
            x_end[:, bad] = x0[:, bad]
            return x_end, ok
        x_end[:, bad], ok[bad] = self._halves(evaluate, ids[bad], x0[:, bad], h, level + 1)
        return x_end, ok
