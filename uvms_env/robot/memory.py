"""What a robot remembers from its own measurements, for ``observation_mode="memory"``: the
last command it sent (8, clipped) and its estimate of the disturbance its model misses (8,
in input units, low-pass filtered with ``DISTURBANCE_GAIN`` and clipped to
+-``DISTURBANCE_LIMIT``; the formula: docs/environment.md, "Memory"; ``disturbance_sx``).

Why: the NMPC expert decides from more than the current observation (its warm-started
plan, a disturbance observer, a goal integral); its action is predicted 30x better with
the previous action added (docs/notes/2026-11-24-expert-initialized-and-shielded-ppo.md).
This memory gives a policy the first two, built only from what the robot measures and
what it sent.

``Memory`` holds the arrays of any batch of robots (the environments' ``EnvCore``, one
robot's policy) and updates them from each period's measurements; ``RobotMemory`` is one
robot's, for a policy that acts from its raw observations (``observe`` then ``issued``):
both run the same compiled function, so a policy rebuilds exactly the memory block the
environment showed it in training.

May import: numpy, casadi and ``uvms_env.dynamics`` and the ``env`` modules of the
observation's layout and the priors.
"""

from __future__ import annotations

import functools
from typing import Any

import casadi as cs
import numpy as np

from uvms_env.dynamics import NQ, NU
from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.local_model import local_terms
from uvms_env.dynamics.payload import object_tag
from uvms_env.dynamics.uvms import default_model
from uvms_env.robot.observation import OBSERVATION_SIZE, OBSERVATION_STRUCTURE
from uvms_env.robot.priors import object_model, own_model_inputs

# A time constant of ~3 periods (0.36 s): it follows a current's slow changes and a
# teammate's pull within a second, and averages the one-period estimate's noise
# (differentiated twists), the centralized NMPC's estimate uses the same gain.
DISTURBANCE_GAIN = 0.3
# In input units: a disturbance past twice the saturation is beyond cancelling anyway, and
# a diverging estimate (a collision, a refused step) must not blow up a network's inputs.
DISTURBANCE_LIMIT = 2.0
_ZETA = OBSERVATION_STRUCTURE["zeta"]


def disturbance_sx(o: cs.SX, zeta_next: cs.SX, command: cs.SX, period: cs.SX, ring: float):
    """d_raw (8): the input that equals the generalized force the local model misses between
    observation ``o`` and the measured twist ``zeta_next`` one ``period`` later under
    ``command``: w = M(x) (zeta' - zeta) / h - B tau_max u - r(x), d_raw = B^T w / tau_max."""
    uvms = default_model()
    x, theta = own_model_inputs(o, ring)
    q, zeta = x[:NQ], x[NQ:]
    mass, force = local_terms(uvms, object_model(ring), q, zeta, theta)
    tau_max = cs.DM(np.asarray(uvms.params.limits.tau_max, float))
    b = cs.DM(uvms.B)
    missed = mass @ (zeta_next - zeta) / period - b @ (tau_max * command) - force
    return (b.T @ missed) / tau_max


@functools.cache
def _update_one(ring: float) -> cs.Function:
    """(o_prev, zeta_now, command, d, period) -> the filtered, clipped estimate after one
    period: d + g (d_raw - d), within +-``DISTURBANCE_LIMIT``."""
    o, zeta = cs.SX.sym("obs", OBSERVATION_SIZE), cs.SX.sym("zeta_next", NQ)
    u, d, h = cs.SX.sym("command", NU), cs.SX.sym("d", NU), cs.SX.sym("period")
    raw = disturbance_sx(o, zeta, u, h, ring)
    new = cs.fmin(DISTURBANCE_LIMIT, cs.fmax(-DISTURBANCE_LIMIT, d + DISTURBANCE_GAIN * (raw - d)))
    name = f"memory_update_{object_tag(ring)}"
    return compile_function(cs.Function(name, [o, zeta, u, d, h], [new], {"cse": True}))


@functools.lru_cache(maxsize=16)
def _update_call(ring: float, count: int) -> BufferCall:
    return BufferCall(_update_one(ring).map(count))


def sent(command: Any, xp: Any = np) -> Any:
    """A command as the robot sends it: clipped to the saturation, in float32 (a policy's
    numbers; the environment's residual command is float64)."""
    return xp.clip(command, -1.0, 1.0).astype(np.float32).astype(np.float64)


class Memory:
    """The memory of a batch of robots, arrays of shape ``batch + (8,)`` in namespace
    ``xp`` (numpy, or CuPy: the compiled update runs on the host). ``ids`` index the
    batch's leading dimensions as the caller's arrays do (``...``: all of them)."""

    def __init__(self, batch: tuple[int, ...], period: float, ring: float, xp: Any = np):
        self.xp, self.period, self.ring = xp, float(period), float(ring)
        self.command = xp.zeros((*batch, NU))
        self.disturbance = xp.zeros((*batch, NU))

    def reset(self, ids: Any) -> None:
        """A new episode for ``ids``: nothing sent, nothing estimated yet."""
        self.command[ids] = 0.0
        self.disturbance[ids] = 0.0

    def update(self, ids: Any, previous: Any, raw: Any, command: Any) -> None:
        """One period of ``ids``: ``previous`` raw observations, ``command`` the inputs
        sent after them, ``raw`` the observations that followed."""
        u = sent(command, self.xp)
        self.disturbance[ids] = self.estimate(ids, previous, raw, u)
        self.command[ids] = u

    def estimate(self, ids: Any, previous: Any, raw: Any, command: Any) -> Any:
        """The disturbance estimate of ``ids`` after the period ``update`` folds in, without
        changing the memory."""
        xp = self.xp
        u = sent(command, xp)
        host = np.asarray if xp is np else xp.asnumpy
        shape = u.shape
        rows = int(np.prod(shape[:-1]))
        columns = (
            host(previous).astype(np.float64).reshape(rows, OBSERVATION_SIZE),
            host(raw)[..., _ZETA].astype(np.float64).reshape(rows, NQ),
            host(u).reshape(rows, NU),
            host(self.disturbance[ids]).reshape(rows, NU),
            np.full((rows, 1), self.period),
        )
        out = _update_call(self.ring, rows)(*(np.ascontiguousarray(c) for c in columns))[0]
        return xp.asarray(out.reshape(shape).copy())

    def block(self, ids: Any) -> Any:
        """The memory of ``ids`` as an observation block ``(..., 16)`` float32."""
        return self.xp.concatenate([self.command[ids], self.disturbance[ids]], -1).astype(
            np.float32
        )


class RobotMemory:
    """One robot's memory for a policy acting on its own raw observations:
    ``observe(raw)`` at each decision (it folds in the last period), ``issued(command)``
    with the normalized input sent, ``executed(command)`` when another controller (a
    safety filter) replaced it. The same compiled update as ``Memory``, through buffers
    bound once (a few microseconds a decision)."""

    def __init__(self, period: float, ring: float) -> None:
        self._prev = np.zeros(OBSERVATION_SIZE)
        self._zeta = np.zeros(NQ)
        self._u = np.zeros(NU)
        self._d = np.zeros(NU)
        self._call = BufferCall(_update_one(float(ring)))
        self._out = self._call(self._prev, self._zeta, self._u, self._d, np.array([period]))[0]
        self._block = np.zeros(2 * NU, np.float32)
        self._f32 = np.zeros(NU, np.float32)
        self._seen = self._sent = False

    def reset(self) -> None:
        self._d[:] = 0.0
        self._block[:] = 0.0
        self._seen = self._sent = False

    def observe(self, raw: np.ndarray) -> np.ndarray:
        """The memory block (16,) float32 for the decision on ``raw`` (79,)."""
        raw = np.asarray(raw, np.float32)[:OBSERVATION_SIZE]
        if self._seen and self._sent:
            self._zeta[:] = raw[_ZETA]
            self._call.again()
            self._d[:] = self._out
            self._block[:NU] = self._u
            self._block[NU:] = self._d
        self._prev[:] = raw
        self._seen, self._sent = True, False
        return self._block.copy()

    def issued(self, command: np.ndarray) -> None:
        """The normalized input (8,) sent after the last ``observe``: ``sent`` in place
        (np.clip's dispatch alone took longer than the compiled update)."""
        u = self._u
        u[:] = command  # (8,) or (1, 8)
        np.minimum(u, 1.0, out=u)
        np.maximum(u, -1.0, out=u)
        self._f32[:] = u
        u[:] = self._f32
        self._sent = True

    executed = issued
