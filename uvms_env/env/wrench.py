"""The internal (squeeze) wrench on the object, fast enough to sample every step.

``Simulator.internal_wrench`` evaluates the closed chain's grasp wrenches through the
CasADi virtual machine and projects them with a pseudo-inverse: ~470 us, more than a
whole simulator step. This is the same quantity as one compiled call (~10 us hot, ~20 us
inside a step): the simulator's own ``chain.wrenches`` function, followed by the
projection onto the null space of the grasp map, written as a 6x6 solve. With
A = G^T = [J_O1^T ... J_ON^T] (full row rank, every J_Oi is invertible),
pinv(A) = A^T (A A^T)^-1 and A A^T = sum_i J_Oi^T J_Oi, so

    lambda_int = lambda - A^T (A A^T)^-1 A lambda.

A test keeps it equal to ``Simulator.internal_wrench``.

May import: numpy, casadi, ``uvms_env.dynamics``, ``uvms_env.sim`` and
``uvms_env.env.kinematics``.
"""

from __future__ import annotations

from functools import cache

import casadi as cs
import numpy as np

from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.payload import grasp_jacobian
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.env.kinematics import grasp_matrix
from uvms_env.sim import Simulator


@cache
def _compiled(wrenches: cs.Function, n: int) -> cs.Function:
    args = [cs.MX.sym(wrenches.name_in(i), wrenches.sparsity_in(i)) for i in range(6)]
    x, grasp = args[0], args[5]
    lam = wrenches(*args)  # 6 x N
    x_o = x[20 * n : 20 * n + 6]
    r_o = rot_zyx(x_o[3:])
    j_o = [grasp_jacobian(r_o, grasp[:3, i]) for i in range(n)]
    a_lam = sum(j.T @ lam[:, i] for i, j in enumerate(j_o))
    a_at = sum(j.T @ j for j in j_o)
    y = cs.solve(a_at, a_lam)
    internal = cs.horzcat(*[lam[:, i] - j @ y for i, j in enumerate(j_o)])
    return compile_function(
        cs.Function(f"internal_wrench_n{n}", args, [internal, cs.sumsqr(internal)])
    )


class InternalWrench:
    """``InternalWrench(sim)(tau_applied, current)`` -> squared Frobenius norm of the
    (N, 6) squeeze after a step; the squeeze itself is then in ``.value``.

    Arguments as in ``StepInfo``: the saturated inputs of the last period and the current
    during it; the state is the simulator's (after the step). ``value`` is overwritten by
    the next call."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self._call = BufferCall(_compiled(sim.chain.wrenches, sim.n))
        self._grasp = grasp_matrix(sim.scenario)
        self.value, self._norm_sq = self._call.outputs

    def __call__(self, tau_applied: np.ndarray, current: np.ndarray) -> float:
        sim = self.sim
        self._call(
            sim.flat_state,
            np.ascontiguousarray(tau_applied, dtype=float),
            np.ascontiguousarray(current, dtype=float),
            sim.parameters,
            sim.object_parameters,
            self._grasp,
        )
        return float(self._norm_sq[0, 0])
