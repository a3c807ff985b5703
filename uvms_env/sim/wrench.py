"""The internal (squeeze) wrench on the object after a step, for the episode metrics.

Thin adapter over ``Simulator.internal_wrench`` (one compiled call), returning
the squared Frobenius norm the metrics accumulate. May import: numpy, ``uvms_env.sim.simulator``.
"""

from __future__ import annotations

import numpy as np

from uvms_env.sim.simulator import Simulator


class InternalWrench:
    """``InternalWrench(sim)(tau_applied)`` -> squared Frobenius norm of the (N, 6)
    squeeze after a step; the squeeze itself is then in ``.value``.

    ``tau_applied`` as in ``StepInfo``: the saturated inputs of the last period; the
    current is the simulator's own record of that period (``Simulator.internal_wrench``)."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.value = np.zeros((sim.n, 6))

    def __call__(self, tau_applied: np.ndarray) -> float:
        self.value = self.sim.internal_wrench(tau_applied)
        return float(np.einsum("ij,ij->", self.value, self.value))
