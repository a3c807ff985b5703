"""K truth simulators of one team size and object, stepped by one compiled call per period
(usage: docs/batched.md).

It is the single ``Simulator`` batched, not a second model: the same compiled period
function for SIMD lanes and threads (``backend="cpu"``) or as a GPU kernel
(``backend="cuda"``; ``device="cpu"``: that kernel's source compiled for the host), the
same error control and envelope (``uvms_env.sim.period.PeriodControl`` over K; on the
CUDA backend in each environment's thread, ``kernels.Refinement``) and the same currents
(``uvms_env.sim.current.Currents``): environment k reset with seed s_k and stepped with
tau_k matches ``Simulator`` to rounding in float64 (docs/batched.md: agreement, float32).

Arrays are laid out with the environment index innermost, (element, K), as the kernels
read them. Environments may differ in geometry (grasps, starts) as long as they share the
team size and the object (``set_scenario``).

May import: numpy (cupy for the CUDA backend), ``uvms_env.sim``, ``uvms_env.dynamics``,
``uvms_env.vector.kernels``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from uvms_env.dynamics import NP, NQ, NU, ObjectModel
from uvms_env.dynamics.uvms import default_model
from uvms_env.sim.chain import NG, state_size
from uvms_env.sim.current import Currents
from uvms_env.sim.period import OK, PeriodControl
from uvms_env.sim.simulator import draw_truth_parameters, grasp_parameters, symbolic_chain
from uvms_env.vector.kernels import DTYPES, REFUSED, BatchedFunction, available_cores

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario

BACKENDS = ("cpu", "cuda")


def check_batch(num_envs: Any, backend: str, dtype: str) -> None:
    """TypeError or ValueError naming the argument unless K = ``num_envs`` is an int >= 1
    and ``backend`` and ``dtype`` are known: checked before anything is built."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer):
        raise TypeError(f"num_envs must be an int >= 1, got {num_envs!r}")
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")


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
        check_batch(num_envs, backend, dtype)
        self.scenario = s = scenario
        self.n = n = s.n_agents
        self.num_envs = k = int(num_envs)
        self.backend, self.dtype = backend, dtype
        self.threads = int(threads or available_cores())
        self.chain = symbolic_chain(n, s.object_shape, s.object_size, s.period, s.substeps)
        if backend == "cpu":
            self._fn: Any = BatchedFunction(self.chain.step, dtype, lanes)
            self.xp: Any = np
        else:
            from uvms_env.vector.kernel_list import period_refinement
            from uvms_env.vector.kernels_cuda import cuda_function

            # the error control runs inside the kernel, in the thread of each environment
            # that needs it: refining a few environments costs no extra launches
            self._fn = cuda_function(
                self.chain.step, dtype, device, self.threads, refine=period_refinement(n, dtype)
            )
            self.xp = self._fn.xp
        xp, real = self.xp, DTYPES[dtype][1]
        self._real = real
        self.uvms = default_model()
        self.object = ObjectModel(s.object_shape, s.object_size)
        self.tau_max = self.uvms.params.limits.tau_max
        self._tau_max = xp.asarray(np.tile(self.tau_max, n)[:, None], real)
        nominal = np.tile(self.uvms.nominal_parameters(), (n, 1))
        self._nominal = (nominal, self.object.nominal_parameters())
        kp = self._fn.padded(k)
        self._kp = kp
        self.x = xp.zeros((state_size(n), kp), real)
        self.parameters = xp.zeros((NP * n, kp), real)
        self.object_parameters = xp.zeros((self.object.parameter_count, kp), real)
        self.grasp = xp.zeros((NG * n, kp), real)
        self._tau = xp.zeros((NU * n, kp), real)
        self._vc = xp.zeros((3, kp), real)
        self._h = xp.full((1, kp), s.period, real)
        nnz_out = self._fn.nnz_out if backend == "cuda" else self._fn.signature.nnz_out
        self._out = [xp.zeros((m, kp), real) for m in nnz_out]
        self.scenarios: list[Scenario] = [s] * k
        self.refinements = 0  # environment-periods integrated in parts (diagnostics)
        self.control = PeriodControl(n, xp, real)
        self._presets = self.uvms.params.currents
        self.currents = Currents(self._presets[s.current], k)
        self._still = True  # the current input _vc is zero
        self.set_scenario(np.arange(k), s)
        self.reset(np.arange(k), [s.seed] * k)

    # -- geometry and episodes -----------------------------------------------------
    def set_scenario(self, env_ids: Any, scenario: Scenario) -> None:
        """Environments ``env_ids`` take ``scenario``'s geometry (same team size, object,
        period and substeps); call ``reset`` for them afterwards."""
        s = scenario
        same, first = (
            (t.n_agents, t.object_shape, float(t.object_size), t.period, t.substeps)
            for t in (s, self.scenario)
        )
        if same != first:
            raise ValueError(
                "a batched simulator's environments share the team size, the object, the "
                f"period and the substeps: {same} differs from the first scenario's"
            )
        grasp = grasp_parameters(s)
        ids = np.atleast_1d(np.asarray(env_ids))
        self.grasp[:, self._cols(ids)] = self.xp.asarray(grasp.reshape(-1)[:, None], self._real)
        for i in ids.tolist():
            self.scenarios[i] = s
        self._fill_padding()

    def reset(
        self,
        env_ids: Any,
        seeds: Any,
        mismatch: Sequence[float | None] | None = None,
        current: Sequence[str | None] | None = None,
    ) -> None:
        """Environments ``env_ids`` back to their scenario's start at rest, with the truth
        model and then the ocean current drawn from ``seeds`` (one per environment) exactly
        as ``Simulator.reset``, under each one's ``mismatch`` and ``current`` preset (None:
        the scenario's)."""
        ids = np.atleast_1d(np.asarray(env_ids))
        seeds = list(seeds) if np.ndim(seeds) else [seeds] * len(ids)
        if len(seeds) != len(ids):
            raise ValueError(f"{len(ids)} environments but {len(seeds)} seeds")
        mismatches = [None] * len(ids) if mismatch is None else list(mismatch)
        presets = [None] * len(ids) if current is None else list(current)
        x = np.zeros((state_size(self.n), len(ids)))
        p = np.zeros((NP * self.n, len(ids)))
        po = np.zeros((self.object.parameter_count, len(ids)))
        generators, drawn = [], []
        for col, (i, seed, m) in enumerate(zip(ids.tolist(), seeds, mismatches, strict=True)):
            s = self.scenarios[i]
            rng = np.random.default_rng(seed if seed is not None else s.seed)
            pi, poi = draw_truth_parameters(s, *self._nominal, rng, m)
            generators.append(rng)
            drawn.append(self._presets[presets[col] or s.current])
            p[:, col], po[:, col] = pi.reshape(-1), poi
            x[:, col] = np.concatenate(
                [s.initial_q.reshape(-1), np.zeros(NQ * self.n), s.object_start, np.zeros(6)]
            )
        self.currents.reset(ids.tolist(), generators, drawn)
        cols, xp = self._cols(ids), self.xp
        self.x[:, cols] = xp.asarray(x, self._real)
        self.parameters[:, cols] = xp.asarray(p, self._real)
        self.object_parameters[:, cols] = xp.asarray(po, self._real)
        self._fill_padding()

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
        saturated at the limits; ``current`` (K, 3): this period's inertial current
        velocity instead of each environment's own (tests, replays). Returns the verdict
        per environment, (K,) int8 (``uvms_env.sim.period``): ``OK``, ``INACCURATE`` (the
        error control failed at 1/16 of a period) or ``ENVELOPE`` (beyond the physical
        envelope); a refused environment keeps its state."""
        xp, k, n = self.xp, self.num_envs, self.n
        tau = xp.asarray(tau)
        if tau.shape != (k, n, NU):
            raise ValueError(f"tau must have shape ({k}, {n}, {NU}), got {tau.shape}")
        if not bool(xp.isfinite(tau).all()):
            bad = int(xp.argwhere(~xp.isfinite(tau.reshape(k, -1)))[0, 0])
            raise ValueError(f"tau contains NaN or inf (environment {bad})")
        self._tau[:, :k] = tau.reshape(k, n * NU).T
        xp.clip(self._tau, -self._tau_max, self._tau_max, out=self._tau)
        self._set_current(current)
        if self.backend == "cuda":
            x_next, ok = self._controlled_step()
        else:
            period = self.scenario.period
            x_next, ok, refined = self.control.integrate(self._evaluate, self.x, period, k)
            self.refinements += refined
        code = self.control.verdict(ok, x_next)
        self.x[:, :k] = xp.where((code == OK)[None, :], x_next, self.x[:, :k])
        return code

    def _set_current(self, current: Any) -> None:
        """This period's current input: ``current`` (K, 3), or the environments' own."""
        xp, k = self.xp, self.num_envs
        if current is None:
            current = self.currents.step(self.scenario.period)
            if current is None:  # still water everywhere: no draws, no transfer
                if not self._still:
                    self._vc[:] = 0.0
                    self._still = True
                return
        current = xp.asarray(current)
        if current.shape != (k, 3):
            raise ValueError(f"current must have shape ({k}, 3), got {current.shape}")
        self._vc[:, :k] = current.T
        self._still = False

    def _inputs(self) -> list:
        """The period step's inputs for every environment (h last)."""
        return [
            self.x,
            self._tau,
            self._vc,
            self.parameters,
            self.object_parameters,
            self.grasp,
            self._h,
        ]

    def _controlled_step(self) -> tuple[Any, Any]:
        """The CUDA kernel's period with its in-thread error control. -> (x_next, ok)."""
        k = self.num_envs
        self._h[:] = self.scenario.period
        outputs = self._fn(self._inputs(), out=self._out)
        status = outputs[3][0, :k]
        self.refinements += int((status > 0).sum())
        return outputs[0][:, :k], status != REFUSED

    def _evaluate(self, ids: Any, x0: Any, h: float) -> tuple[Any, ...]:
        """The period routine's compiled call (``uvms_env.sim.period.Evaluate``) on the CPU
        lanes: every environment into the step's buffers, or environments ``ids`` from
        ``x0`` gathered (padded to the lanes) into new arrays."""
        xp, threads = self.xp, self.threads
        if ids is None:
            self._h[:] = h
            return tuple(self._fn(self._inputs(), threads, out=self._out)[:3])
        m = len(ids)
        mp = self._fn.padded(m)
        cols = xp.concatenate([ids, xp.full(mp - m, ids[0], ids.dtype)]) if mp > m else ids
        x_in = xp.concatenate([x0, x0[:, :1].repeat(mp - m, axis=1)], axis=1) if mp > m else x0
        per_env = [xp.ascontiguousarray(a[:, cols]) for a in self._inputs()[1:-1]]  # x ... h
        ins = [xp.ascontiguousarray(x_in), *per_env, xp.full((1, mp), h, self._real)]
        return tuple(self._fn(ins, threads))

    def _cols(self, ids: np.ndarray) -> Any:
        return self.xp.asarray(ids) if self.backend == "cuda" else ids
