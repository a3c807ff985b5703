"""The model object handed to the centralized NMPC: the team's prediction model, numeric.

    model = TeamModel(scenario, horizon)                  # nominal parameters
    wrong = TeamModel(scenario, horizon, parameters=p)    # a deliberately wrong model
    team = CentralNMPC(scenario, model=wrong)

As safe-control-gym hands a controller one symbolic model object, the centralized
controller (``central``) is handed this one: the compiled functions of ``central_model``
(the simulator's own period step and the linearization of the chain's rhs) bound to the
parameters they are evaluated at (the nominal ones unless given), the grasps and the
input scale, with the calls the controller makes (``step``, ``linearize``). Building it
needs no simulator.

May import: numpy, ``uvms_env`` (dynamics, sim, scenarios) and this package's
``central_model``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmpc_expert.central_model import CentralFunctions, central_functions
from uvms_env.dynamics import NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.dynamics.uvms import default_model
from uvms_env.scenarios import Scenario
from uvms_env.sim.chain import state_size
from uvms_env.sim.simulator import grasp_parameters

# Relative forward-difference step of the state Jacobian (``central_model``).
FD_STEP = 1e-6


@dataclass(frozen=True)
class TeamLinearization:
    """One ``TeamModel.linearize``: (Phi, Gamma) of one period at the plan's first node,
    frozen over the horizon, and the squeeze and manipulability along the plan (buffers of
    the compiled call: valid until the next one)."""

    phi: np.ndarray  # (nx, nx)
    gamma: np.ndarray  # (nx, N * 8), per normalized input
    squeeze: np.ndarray  # (horizon + 1, 6 N): the internal wrench at each node
    squeeze_input: np.ndarray  # (6 N, N * 8): its exact input Jacobian at the first node
    manipulability: np.ndarray  # (horizon + 1, N)
    manipulability_gradient: np.ndarray  # ((horizon + 1) N, NQ): over each robot's q


class TeamModel:
    """The team's prediction model over a horizon (see module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        horizon: int,
        parameters: np.ndarray | None = None,
        object_parameters: np.ndarray | None = None,
    ) -> None:
        """``parameters`` (N, NP) and ``object_parameters`` (the object's p_O, its shape
        included): those the model is evaluated at; None: the nominal ones (the
        simulator's before a mismatch draw)."""
        s = self.scenario = scenario
        self.n, self.horizon = n, hz = s.n_agents, int(horizon)
        self.period, self.substeps = s.period, s.substeps
        self.nx, self.nu = state_size(n), NU * n
        uvms = default_model()
        nominal = np.tile(uvms.nominal_parameters(), (n, 1))
        obj = ObjectModel(s.object_shape, s.object_size)
        nominal_object = obj.nominal_parameters()
        self.parameters = _checked(parameters, nominal, "parameters")
        self.object_parameters = _checked(object_parameters, nominal_object, "object_parameters")
        self.grasp = grasp_parameters(s)
        self.tau_max = np.asarray(uvms.params.limits.tau_max, dtype=float)
        self.functions: CentralFunctions = central_functions(
            n, obj.capacity, s.period, s.substeps, hz + 1
        )
        self._step = BufferCall(self.functions.step)
        self._lin = BufferCall(self.functions.linearization)
        # the compiled calls' bound inputs (re-binding a new array costs a call)
        self._x = np.zeros(self.nx)
        self._tau = np.zeros((n, NU))
        self._current = np.zeros(3)  # the controller models no current
        self._h = np.array([s.period])
        self._a0 = np.zeros((n, NU))
        self._a_nodes = np.zeros((hz + 1, n, NU))
        self._eps = np.array([FD_STEP])

    def step(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The state (nx,) one period after ``x`` (nx,) under normalized inputs ``a``
        (N, 8): the compiled step's output buffer, valid until the next call."""
        self._x[:] = x
        np.multiply(a, self.tau_max, out=self._tau)
        p, po = self.parameters, self.object_parameters
        out = self._step(self._x, self._tau, self._current, p, po, self.grasp, self._h)
        return out[0].reshape(-1)

    def predict(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``step``, checked and copied: the state after one period (nx,) from the team
        state ``x`` (nx,) under normalized inputs ``a`` (N, 8)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        a = np.asarray(a, dtype=np.float64)
        if x.shape != (self.nx,) or a.shape != (self.n, NU):
            raise ValueError(f"expected x ({self.nx},) and a ({self.n}, {NU})")
        return self.step(x, a).copy()

    def linearize(self, xbar: np.ndarray, abar: np.ndarray) -> TeamLinearization:
        """One compiled call along the plan (``xbar`` (horizon + 1, nx), ``abar``
        (horizon, N, 8)): the rhs Jacobians at its first node, discretized, and the squeeze
        and manipulability at every node (the last input repeated at the last node)."""
        hz = self.horizon
        self._x[:] = xbar[0]
        self._a0[:] = abar[0]
        self._a_nodes[:hz] = abar
        self._a_nodes[hz] = abar[-1]
        p, po = self.parameters, self.object_parameters
        args = (self._x, self._a0, xbar, self._a_nodes, p, po, self.grasp, self._eps)
        _, jx_t, ju_t, w_t, wu_t, m_t, jm_t = self._lin(*args)
        phi, gamma = self.discretize(jx_t.T, ju_t.T)
        return TeamLinearization(phi, gamma, w_t, wu_t.T, m_t, jm_t)

    def discretize(self, jx: np.ndarray, ju: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma) of one period: the simulator's own integrator (``substeps``
        classical RK4 steps) applied to the linearized dynamics x' = Jx x + Ju a. One RK4
        step of a linear system is the 4th-order Taylor polynomial S of expm(dt Jx) (and
        of its integral for the input), as ``ocp.build_interval`` chains it symbolically
        per substep; here the Jacobian is frozen over the period, so ``substeps`` steps
        are S^substeps, by repeated squaring. (scipy's ``expm`` of the same matrix took
        3 ms at N = 6: the badly scaled Jacobian's norm, ~700 per period, forces many
        squarings; this is ~0.6 ms.)"""
        steps = self.substeps
        dt = self.period / steps
        m = dt * jx
        eye = np.eye(len(jx))
        # Horner: S = I + m (I + m/2 (I + m/3 (I + m/4))), U = dt (I + m/2 + m^2/6 + m^3/24) Ju
        p = eye + m / 4
        p = eye + (m @ p) / 3
        taylor = eye + (m @ p) / 2  # I + m/2 + m^2/6 + m^3/24
        s_mat = eye + m @ taylor
        phi, gam = s_mat, dt * (taylor @ ju)
        done = 1
        while done * 2 <= steps:  # doubling: (S^k, Gamma_k) -> (S^2k, S^k Gamma_k + Gamma_k)
            gam = phi @ gam + gam
            phi = phi @ phi
            done *= 2
        for _ in range(steps - done):  # what doubling leaves (steps not a power of 2)
            gam = s_mat @ gam + dt * (taylor @ ju)
            phi = s_mat @ phi
        return phi, gam


def _checked(given: np.ndarray | None, nominal: np.ndarray, name: str) -> np.ndarray:
    """``given`` (or ``nominal`` when None) as a C-contiguous float64 copy of its shape."""
    value = nominal if given is None else np.asarray(given, dtype=np.float64)
    if value.shape != nominal.shape or not np.all(np.isfinite(value)):
        raise ValueError(f"{name} must be finite, of shape {nominal.shape}, got {value.shape}")
    return np.array(value, dtype=np.float64, order="C")
