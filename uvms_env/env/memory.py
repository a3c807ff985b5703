"""What a robot remembers from its own measurements, for ``observation_mode="memory"``: the
last command it sent and its estimate of the disturbance its model misses.

The NMPC expert decides from more than the current observation: its warm-started plan
(its last input), a disturbance observer and a goal integral. A policy of the current
observation alone cannot reproduce that (docs/notes/2026-11-24-expert-initialized-and-
shielded-ppo.md: the expert's action is predicted 30x better with the previous action
added). This memory gives a policy the first two, built only from what the robot measures
and what it sent:

* **command** (8): the normalized input the robot sent last period, clipped to [-1, 1]
  (zeros at the start of an episode);
* **disturbance** (8): the generalized force its local model misses, in input units. From
  the previous measured state x = (q, zeta), the command u and the measured twist
  zeta' one period h later, w = M(x) (zeta' - zeta) / h - B tau_max u - r(x), with M and r
  the local model's mass matrix and forces (``uvms_env.dynamics.local_model.local_terms``,
  the expert's own model, nominal parameters, no current); d_raw = B^T w / tau_max is the
  input that would produce w (surge, sway, heave, yaw and the four joints; roll and pitch
  are passive). The estimate is low-pass filtered, d <- d + ``DISTURBANCE_GAIN`` (d_raw - d),
  and clipped to +-``DISTURBANCE_LIMIT``. A current, a mismatched mass or drag and a
  teammate's pull all show up in d; minus d is the input that cancels them.

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
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.observation import OBSERVATION_SIZE, OBSERVATION_STRUCTURE
from uvms_env.env.priors import object_model, own_model_inputs

MEMORY_SIZE = 2 * NU  # the command, then the disturbance estimate
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
    ``command`` (module docstring)."""
    uvms = default_model()
    x, theta = own_model_inputs(o, ring)
    q, zeta = x[:NQ], x[NQ:]
    mass, force = local_terms(uvms, object_model(ring), q, zeta, theta)
    tau_max = cs.DM(np.asarray(uvms.params.limits.tau_max, float))
    b = cs.DM(uvms.B)
    missed = mass @ (zeta_next - zeta) / period - b @ (tau_max * command) - force
    return (b.T @ missed) / tau_max


@functools.cache
def _disturbance_one(ring: float) -> cs.Function:
    o, zeta = cs.SX.sym("obs", OBSERVATION_SIZE), cs.SX.sym("zeta_next", NQ)
    u, h = cs.SX.sym("command", NU), cs.SX.sym("period")
    name = f"memory_disturbance_{ring:.4f}".replace(".", "p")
    fn = cs.Function(name, [o, zeta, u, h], [disturbance_sx(o, zeta, u, h, ring)], {"cse": True})
    return compile_function(fn)


@functools.lru_cache(maxsize=16)
def _disturbance_call(ring: float, count: int) -> BufferCall:
    return BufferCall(_disturbance_one(ring).map(count))


def measured_disturbance(
    previous: np.ndarray, raw: np.ndarray, command: np.ndarray, period: float, ring: float
) -> np.ndarray:
    """d_raw (..., 8) float64 of robots whose raw observations were ``previous`` (..., 79)
    and are now ``raw`` after ``command`` (..., 8) for one ``period``."""
    prev = np.ascontiguousarray(np.asarray(previous, np.float64).reshape(-1, OBSERVATION_SIZE))
    zeta = np.ascontiguousarray(np.asarray(raw, np.float64)[..., _ZETA].reshape(-1, NQ))
    u = np.ascontiguousarray(np.asarray(command, np.float64).reshape(-1, NU))
    h = np.full((len(prev), 1), float(period))
    out = _disturbance_call(float(ring), len(prev))(prev, zeta, u, h)[0]
    return out.reshape(*np.shape(command)[:-1], NU).copy()


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
        xp = self.xp
        # as a policy sends it: float32 (the environment's residual command is float64)
        u = xp.clip(command, -1.0, 1.0).astype(np.float32).astype(np.float64)
        host = np.asarray if xp is np else xp.asnumpy
        d_raw = xp.asarray(
            measured_disturbance(host(previous), host(raw), host(u), self.period, self.ring)
        )
        d = self.disturbance[ids]
        d = xp.clip(d + DISTURBANCE_GAIN * (d_raw - d), -DISTURBANCE_LIMIT, DISTURBANCE_LIMIT)
        self.disturbance[ids] = d
        self.command[ids] = u

    def block(self, ids: Any) -> Any:
        """The memory of ``ids`` as an observation block ``(..., 16)`` float32."""
        return self.xp.concatenate([self.command[ids], self.disturbance[ids]], -1).astype(
            np.float32
        )


class RobotMemory:
    """One robot's memory for a policy acting on its own raw observations:
    ``observe(raw)`` at each decision (it folds in the last period), ``issued(command)``
    with the normalized input sent, ``executed(command)`` when another controller (a
    safety filter) replaced it."""

    def __init__(self, period: float, ring: float) -> None:
        self._memory = Memory((), period, ring)
        self._last_raw: np.ndarray | None = None
        self._last_command: np.ndarray | None = None

    def reset(self) -> None:
        self._memory.reset(...)
        self._last_raw = self._last_command = None

    def observe(self, raw: np.ndarray) -> np.ndarray:
        """The memory block (16,) float32 for the decision on ``raw`` (79,)."""
        raw = np.asarray(raw, np.float32)
        if self._last_raw is not None and self._last_command is not None:
            self._memory.update(..., self._last_raw, raw, self._last_command)
        self._last_raw = raw.copy()
        self._last_command = None
        return self._memory.block(...)

    def issued(self, command: np.ndarray) -> None:
        """The normalized input (8,) sent after the last ``observe``."""
        self._last_command = np.asarray(command, np.float64).reshape(NU).copy()

    executed = issued
