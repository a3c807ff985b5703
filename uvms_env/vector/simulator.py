"""K truth simulators of one team size and object, stepped by one compiled call per period.

    bsim = BatchedSimulator(make("paper"), num_envs=1024, backend="cpu", dtype="float64")
    bsim.reset(seeds=np.arange(1024))
    diverged = bsim.step(tau)          # tau (K, N, 8) physical units, saturated inside
    bsim.state()                       # (K, 20 N + 12) flat states, as Simulator.flat_state

It is the single ``Simulator`` batched, not a second model: the same compiled period
function (RK4 substeps, projection onto the grasp manifold, residuals before and after),
generated once and compiled for SIMD lanes and threads (``backend="cpu"``) or as a GPU
kernel (``backend="cuda"``, arrays stay on GPU ``device``; ``device="cpu"``: that kernel's
source compiled for the host, for tests without a GPU), the same error control (a period
whose drift exceeds the tolerances is integrated again in halves, only for the
environments that need it) and the same physical envelope. Environment k reset with
seed s_k and stepped with tau_k matches ``Simulator`` reset with s_k and stepped with
tau_k: to rounding in float64 (the tests hold it to 1e-12 over hundreds of periods);
float32 is the fast mode, its deviation measured in the tests.

Arrays are laid out with the environment index innermost, (element, K), as the kernels
read them. The ocean current is an input of ``step`` (zero by default) rather than drawn
here: its per-environment random walk belongs with the environment's other draws.
Environments may differ in geometry (grasps, starts) as long as they share the team
size and the object (``set_scenario``).

May import: numpy (cupy for the CUDA backend), ``uvms_env.sim``, ``uvms_env.dynamics``,
``uvms_env.vector.kernels``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from uvms_env.dynamics import NP, NQ, NU, ObjectModel
from uvms_env.dynamics.payload import NPO
from uvms_env.dynamics.uvms import default_model
from uvms_env.sim.chain import NG, state_size
from uvms_env.sim.simulator import (
    DRIFT_TOL_POSE,
    DRIFT_TOL_TWIST,
    GRASP_TOL,
    MAX_REFINEMENTS,
    SPEED_LIMITS,
    _chain,
    draw_truth_parameters,
)
from uvms_env.vector.kernels import DTYPES, BatchedFunction, available_cores

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario

BACKENDS = ("cpu", "cuda")
# Why an environment's last step was refused (``step``'s return value).
OK, INACCURATE, ENVELOPE = 0, 1, 2


class BatchedSimulator:
    """K truth simulators stepped together (see module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        num_envs: int,
        backend: str = "cpu",
        dtype: str = "float64",
        threads: int | None = None,
        lanes: int | None = None,
        device: int | str = 0,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
        if not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.scenario = s = scenario
        self.n = n = s.n_agents
        self.num_envs = k = int(num_envs)
        self.backend, self.dtype = backend, dtype
        self.threads = int(threads or available_cores())
        self.chain, _ = _chain(n, s.object_shape, float(s.ring_radius), s.period, s.substeps)
        if backend == "cpu":
            self._fn: Any = BatchedFunction(self.chain.step, dtype, lanes)
            self.xp: Any = np
        else:
            from uvms_env.vector.kernel_list import period_refinement
            from uvms_env.vector.kernels_cuda import cuda_function

            # the error control runs inside the kernel, in the thread of each environment
            # that needs it: refining a few environments costs no extra launches
            self._fn = cuda_function(
                self.chain.step, dtype, device, self.threads, refine=period_refinement(n)
            )
            self.xp = self._fn.xp
        xp, real = self.xp, DTYPES[dtype][1]
        self._real = real
        self.uvms = default_model()
        self.object = ObjectModel(s.object_shape, s.ring_radius)
        self.tau_max = self.uvms.params.limits.tau_max
        self._tau_max = xp.asarray(np.tile(self.tau_max, n)[:, None], real)
        nominal = np.tile(self.uvms.nominal_parameters(), (n, 1))
        self._nominal = (nominal, self.object.nominal_parameters())
        kp = self._fn.padded(k)
        self._kp = kp
        self.x = xp.zeros((state_size(n), kp), real)
        self.parameters = xp.zeros((NP * n, kp), real)
        self.object_parameters = xp.zeros((NPO, kp), real)
        self.grasp = xp.zeros((NG * n, kp), real)
        self._tau = xp.zeros((NU * n, kp), real)
        self._vc = xp.zeros((3, kp), real)
        self._h = xp.full((1, kp), s.period, real)
        nnz_out = self._fn.nnz_out if backend == "cuda" else self._fn.signature.nnz_out
        self._out = [xp.zeros((m, kp), real) for m in nnz_out]
        self.scenarios: list[Scenario] = [s] * k
        self.refinements = 0  # environment-periods integrated in parts (diagnostics)
        self.set_scenario(np.arange(k), s)
        self.reset(np.arange(k), [s.seed] * k)

    # -- geometry and episodes -----------------------------------------------------
    def set_scenario(self, env_ids: Any, scenario: Scenario) -> None:
        """Environments ``env_ids`` take ``scenario``'s geometry (same team size, object,
        period and substeps); call ``reset`` for them afterwards."""
        s = scenario
        base = self.scenario
        same = (s.n_agents, s.object_shape, float(s.ring_radius), s.period, s.substeps)
        if same != (
            base.n_agents,
            base.object_shape,
            float(base.ring_radius),
            base.period,
            base.substeps,
        ):
            raise ValueError(
                "a batched simulator's environments share the team size, the object, the "
                f"period and the substeps: {same} differs from the first scenario's"
            )
        grasp = np.hstack([s.grasp_offsets, s.grasp_rotations.transpose(0, 2, 1).reshape(-1, 9)])
        ids = np.atleast_1d(np.asarray(env_ids))
        self.grasp[:, self._cols(ids)] = self.xp.asarray(grasp.reshape(-1)[:, None], self._real)
        for i in ids.tolist():
            self.scenarios[i] = s
        self._fill_padding()

    def reset(
        self, env_ids: Any, seeds: Any, mismatch: Sequence[float | None] | None = None
    ) -> list[np.random.Generator]:
        """Environments ``env_ids`` back to their scenario's start at rest, with the truth
        model drawn from ``seeds`` (one per environment) exactly as ``Simulator.reset``,
        under each one's ``mismatch`` (None: the scenario's). Returns each environment's
        generator after those draws: ``Simulator.reset`` goes on to draw the ocean current
        from it, and so does a caller that keeps currents."""
        ids = np.atleast_1d(np.asarray(env_ids))
        seeds = list(seeds) if np.ndim(seeds) else [seeds] * len(ids)
        if len(seeds) != len(ids):
            raise ValueError(f"{len(ids)} environments but {len(seeds)} seeds")
        mismatches = [None] * len(ids) if mismatch is None else list(mismatch)
        x = np.zeros((state_size(self.n), len(ids)))
        p = np.zeros((NP * self.n, len(ids)))
        po = np.zeros((NPO, len(ids)))
        generators = []
        for col, (i, seed, m) in enumerate(zip(ids.tolist(), seeds, mismatches, strict=True)):
            s = self.scenarios[i]
            rng = np.random.default_rng(seed if seed is not None else s.seed)
            pi, poi = draw_truth_parameters(s, *self._nominal, rng, m)
            generators.append(rng)
            p[:, col], po[:, col] = pi.reshape(-1), poi
            x[:, col] = np.concatenate(
                [s.initial_q.reshape(-1), np.zeros(NQ * self.n), s.object_start, np.zeros(6)]
            )
        cols, xp = self._cols(ids), self.xp
        self.x[:, cols] = xp.asarray(x, self._real)
        self.parameters[:, cols] = xp.asarray(p, self._real)
        self.object_parameters[:, cols] = xp.asarray(po, self._real)
        self._fill_padding()
        return generators

    def _fill_padding(self) -> None:
        """The lanes past K (padding to the lane count) mirror environment 0, so that
        they compute finite, ordinary numbers."""
        k = self.num_envs
        for a in (self.x, self.parameters, self.object_parameters, self.grasp):
            a[:, k:] = a[:, :1]

    def state(self) -> Any:
        """(K, 20 N + 12) flat states (a copy; CuPy array on the CUDA backend)."""
        return self.x[:, : self.num_envs].T.copy()

    def set_state(self, x: Any) -> None:
        """Overwrite every environment's flat state (K, 20 N + 12): tests and replays."""
        self.x[:, : self.num_envs] = self.xp.asarray(x, self._real).T

    # -- stepping ------------------------------------------------------------------------
    def step(self, tau: Any, current: Any = None) -> Any:
        """One control period for every environment: ``tau`` (K, N, 8) physical inputs,
        saturated at the limits; ``current`` (K, 3) inertial current velocity during the
        period (default zero). Returns the refusal code per environment, (K,) int8:
        ``OK``, ``INACCURATE`` (the error control failed at 1/16 of a period) or
        ``ENVELOPE`` (beyond the physical envelope); a refused environment keeps its
        state."""
        xp, k, n = self.xp, self.num_envs, self.n
        tau = xp.asarray(tau)
        if tau.shape != (k, n, NU):
            raise ValueError(f"tau must have shape ({k}, {n}, {NU}), got {tau.shape}")
        if not bool(xp.isfinite(tau).all()):
            bad = int(xp.argwhere(~xp.isfinite(tau.reshape(k, -1)))[0, 0])
            raise ValueError(f"tau contains NaN or inf (environment {bad})")
        self._tau[:, :k] = tau.reshape(k, n * NU).T
        xp.clip(self._tau, -self._tau_max, self._tau_max, out=self._tau)
        if current is not None:
            current = xp.asarray(current)
            if current.shape != (k, 3):
                raise ValueError(f"current must have shape ({k}, 3), got {current.shape}")
            self._vc[:, :k] = current.T
        self._h[:] = self.scenario.period
        outputs = self._fn(
            [
                self.x,
                self._tau,
                self._vc,
                self.parameters,
                self.object_parameters,
                self.grasp,
                self._h,
            ],
            **self._call_options(),
            out=self._out,
        )
        x_next, drift, error = outputs[:3]
        code = xp.zeros(self._kp, np.int8)
        if self.backend == "cuda":  # refined in the kernel; its status says how it went
            status = outputs[3][0]
            self.refinements += int((status[:k] > 0).sum())
            # where, not a boolean-mask assignment: CuPy reads a mask's count (a sync)
            code = xp.where(status == 2, INACCURATE, OK).astype(np.int8)
        else:
            bad = np.flatnonzero(~self._accurate(drift, error, x_next)[:k])
            if len(bad):
                self.refinements += len(bad)
                x_end, ok = self._integrate(bad, self.x[:, bad], self.scenario.period, 1)
                x_next[:, bad] = x_end
                code[bad[~ok]] = INACCURATE
        refused = (code == OK) & ~self._within_envelope(x_next)
        code = xp.where(refused, ENVELOPE, code).astype(np.int8, copy=False)
        keep = code[:k] == OK
        self.x[:, :k] = xp.where(keep[None, :], x_next[:, :k], self.x[:, :k])
        return code[:k]

    def _call_options(self) -> dict:
        return {"threads": self.threads} if self.backend == "cpu" else {}

    def _accurate(self, drift: Any, error: Any, x_next: Any) -> Any:
        """Per environment: the error control of ``Simulator._accurate``."""
        xp, n = self.xp, self.n
        d = xp.abs(drift).reshape(n, 12, -1)
        ok = (d[:, :6].max(axis=(0, 1)) <= DRIFT_TOL_POSE) & (
            d[:, 6:].max(axis=(0, 1)) <= DRIFT_TOL_TWIST
        )
        ok &= xp.abs(error).max(axis=0) <= GRASP_TOL
        return ok & xp.isfinite(x_next).all(axis=0)

    def _within_envelope(self, x: Any) -> Any:
        xp, n = self.xp, self.n
        zeta = xp.abs(x[NQ * n : 2 * NQ * n]).reshape(n, NQ, -1)
        v_o = xp.abs(x[2 * NQ * n + 6 :])
        linear = xp.maximum(zeta[:, :3].max(axis=(0, 1)), v_o[:3].max(axis=0))
        angular = xp.maximum(zeta[:, 3:6].max(axis=(0, 1)), v_o[3:].max(axis=0))
        joint = zeta[:, 6:].max(axis=(0, 1))
        return (
            (linear <= SPEED_LIMITS["linear"])
            & (angular <= SPEED_LIMITS["angular"])
            & (joint <= SPEED_LIMITS["joint"])
        )

    def _attempt(self, ids: Any, x0: Any, h: float, level: int) -> tuple[Any, Any]:
        """One evaluation of period part ``h`` for environments ``ids`` from ``x0``; the
        inaccurate ones are integrated in halves (recursively). -> (x_end, ok)."""
        xp = self.xp
        m = len(ids)
        mp = self._fn.padded(m)
        cols = xp.concatenate([ids, xp.full(mp - m, ids[0], ids.dtype)]) if mp > m else ids
        x_in = xp.concatenate([x0, x0[:, :1].repeat(mp - m, axis=1)], axis=1) if mp > m else x0
        ins = [
            xp.ascontiguousarray(x_in),
            xp.ascontiguousarray(self._tau[:, cols]),
            xp.ascontiguousarray(self._vc[:, cols]),
            xp.ascontiguousarray(self.parameters[:, cols]),
            xp.ascontiguousarray(self.object_parameters[:, cols]),
            xp.ascontiguousarray(self.grasp[:, cols]),
            xp.full((1, mp), h, self._real),
        ]
        x_next, drift, error = self._fn(ins, **self._call_options())
        x_end, ok = x_next[:, :m], self._accurate(drift, error, x_next)[:m]
        bad = xp.flatnonzero(~ok)
        if len(bad):
            if level >= MAX_REFINEMENTS:
                return x_end, ok
            x_fix, ok_fix = self._integrate(ids[bad], x0[:, bad], h, level + 1)
            x_end[:, bad] = x_fix
            ok[bad] = ok_fix
        return x_end, ok

    def _integrate(self, ids: Any, x0: Any, h: float, level: int) -> tuple[Any, Any]:
        """Period part ``h`` as two halves for environments ``ids``. -> (x_end, ok)."""
        x_mid, ok_first = self._attempt(ids, x0, h / 2, level)
        x_end, ok_second = self._attempt(ids, x_mid, h / 2, level)
        return x_end, ok_first & ok_second

    def _cols(self, ids: np.ndarray) -> Any:
        return self.xp.asarray(ids) if self.backend == "cuda" else ids
