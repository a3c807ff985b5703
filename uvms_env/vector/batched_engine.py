"""The physics of K environments for ``EnvCore``: compiled calls over all of them at once.

``BatchedEngine`` is the engine ``VectorEnv`` runs (``uvms_env.env.core``, batch shape
B = (K,)): the truth simulator batched (``BatchedSimulator``), the kinematics kernel of the
single environment (``uvms_env.task.team_kernel.team_function``: observations, pose estimates,
constraint values, team reductions, each robot's waypoint sequencing and navigation twist
with the scene's navigation parameters as inputs: one function for every geometry; where
the internal wrench is switched on, the chain's in the same call). Each is a
``BatchedFunction`` (SIMD lanes, threads over cores) or, on the CUDA backend, a GPU kernel
of the same generated source.
Arrays are laid out (element, K padded), the environment index innermost, as the kernels
read them; the ocean currents are the batched simulator's.

May import: numpy, ``uvms_env`` below ``vector`` (the ``env`` kernels and constants it
batches) and the sibling ``vector`` modules.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.dynamics import NQ, NU
from uvms_env.env.core import Engine
from uvms_env.env.options import EnvSetup
from uvms_env.navigation.parametric import NAV_PARAMETERS
from uvms_env.robot.observation import OBSERVATION_SIZE
from uvms_env.robot.priors import BASE_FEATURES, Priors
from uvms_env.scenarios import Scenario, max_waypoints
from uvms_env.scenarios.bank import navigation_table
from uvms_env.sim.period import ENVELOPE, INACCURATE, MAX_REFINEMENTS, OK
from uvms_env.task.conditions import Conditions
from uvms_env.task.team_kernel import (
    CYLINDER_SLOTS,
    ROBOT_SCALARS,
    ROBOT_VIOLATED,
    SPHERE_SLOTS,
    WAYPOINT_SLOTS,
    obstacle_inputs,
    segment_inputs,
)
from uvms_env.task.team_rows import NK, TEAM_INPUT
from uvms_env.vector.batched_simulator import BatchedSimulator
from uvms_env.vector.kernel_list import kernel_functions
from uvms_env.vector.kernels import BatchedFunction

DIVERGED_REASONS = {
    INACCURATE: (
        f"a 1/{2**MAX_REFINEMENTS} part of the period still drifted from the grasps beyond "
        "the error control's tolerance"
    ),
    ENVELOPE: "a speed went beyond the model's physical envelope (SPEED_LIMITS)",
}


class BatchedEngine(Engine):
    """K environments' physics on one backend (module docstring)."""

    def __init__(
        self,
        setup: EnvSetup,
        num_envs: int,
        backend: str,
        dtype: str,
        threads: int,
        lanes: int | None,
        device: int | str,
    ) -> None:
        base = setup.scenario
        self.setup = setup
        self.k = k = num_envs
        self.n = n = base.n_agents
        self.backend, self.dtype, self.threads = backend, dtype, threads
        self.device = device if backend == "cuda" else "cpu"
        self.sim = BatchedSimulator(base, k, backend, dtype, threads, lanes, device)
        self.xp = xp = self.sim.xp  # numpy, or CuPy on a GPU: the per-step arrays live there
        self._lanes = self.sim._fn.lanes if backend == "cpu" else 1
        self._kp = self.sim._kp
        self._real = self.sim._real
        self.noisy = base.sensor_noise > 0
        self.tau_max = xp.asarray(self.sim.tau_max)  # the saturations, where the step runs
        segments = self.sim.object.segments
        self._n_seg = len(segments)
        # the priors' a_ss and features: host calls on the CPU backend (the single env's),
        # kernels of the same CasADi expressions on the GPU, over the K N robots' columns
        priors = backend == "cuda" and setup.priors.needs_steady
        self._w = w = max(max_waypoints(setup.family, base), WAYPOINT_SLOTS)
        self._wrench = setup.internal_wrench_every > 0  # the kernel samples it too
        fns = kernel_functions(
            n,
            self._n_seg,
            self.noisy,
            self.sim.chain,
            self._wrench,
            prior_object_key=base.object_key if priors else None,
            waypoints=w,
        )
        self._kinematics = self._kernel(fns["kinematics"])
        self._prior_kernels = None
        if priors:
            self._prior_kernels = (
                self._kernel(fns["prior_steady"]),
                self._kernel(fns["prior_features"]),
            )
        self._inputs(segments)
        self._nav_tables: dict[int, np.ndarray] = {}  # id(scenario) -> navigation table
        self._scenarios: list[Scenario] = [base] * k  # kept: their ids key the tables
        self._code = xp.zeros(k, np.int64)

    def _inputs(self, segments: Any) -> None:
        """The kinematics kernel's per-environment inputs, (nnz, K padded)."""
        xp, n, kp, real = self.xp, self.n, self._kp, self._real
        z = lambda rows: xp.zeros((rows, kp), real)  # noqa: E731
        self._a = z(NU * n)
        self._q_meas, self._zeta_meas = z(NQ * n), z(NQ * n)
        self._static, self._robots, self._team = z(13 * n), z(2 * n), z(TEAM_INPUT)
        self._waypoints, self._count = z(NAV_PARAMETERS * self._w), z(1)
        self._goal, self._time_fraction = z(6), z(1)
        self._segments = z(6 * self._n_seg)
        self._cylinders, self._spheres = z(4 * CYLINDER_SLOTS), z(5 * SPHERE_SLOTS)
        self._workspace = z(4)
        self._segments[:] = xp.asarray(segment_inputs(segments, self._n_seg).reshape(-1, 1))
        # views of the true state made once: the kernels keep the addresses of the
        # argument lists they see again (``BatchedFunction``), new views are new lists
        x = self.sim.x
        self._truth = (x[: NQ * n], x[NQ * n : 2 * NQ * n], x[2 * NQ * n : 2 * NQ * n + 6])
        self._kin_out = [xp.zeros((m, kp), real) for m in self._kinematics.signature.nnz_out]

    # -- backends -----------------------------------------------------------------------
    def _kernel(self, fn: Any) -> Any:
        """``fn`` batched for this backend: CPU lanes and threads, or a CUDA kernel (on a
        GPU, or with ``device="cpu"`` its source compiled for the host)."""
        if self.backend == "cpu":
            return BatchedFunction(fn, self.dtype, self._lanes)
        from uvms_env.vector.kernels_cuda import cuda_function

        return cuda_function(fn, self.dtype, self.device, self.threads)

    def _call(self, kernel: Any, inputs: list, out: list | None = None) -> list:
        if self.backend == "cpu":
            return kernel(inputs, self.threads, out=out)
        return kernel(inputs, out=out)

    def _on_device(self, ids: Any) -> Any:
        """Host indices as the step's arrays take them (slices pass through)."""
        return ids if isinstance(ids, slice) or self.xp is np else self.xp.asarray(ids)

    # -- geometry and episodes ----------------------------------------------------------
    def set_geometry(self, rows: list[int], scenarios: list[Scenario]) -> None:
        """Kernel inputs, navigation parameters and simulator grasps of ``rows`` (gathered
        on the host, written with one copy per array: one transfer on a GPU)."""
        m, n = len(rows), self.n
        nav, count = np.zeros((m, self._w, NAV_PARAMETERS)), np.zeros((1, m))
        cylinders, spheres = np.zeros((4 * CYLINDER_SLOTS, m)), np.zeros((5 * SPHERE_SLOTS, m))
        workspace, goal, static = np.zeros((4, m)), np.zeros((6, m)), np.zeros((13 * n, m))
        for row, (i, s) in enumerate(zip(rows, scenarios, strict=True)):
            self.sim.set_scenario([i], s)
            self._scenarios[i] = s
            nav[row, : len(s.waypoints)] = self._navigation_table_of(s)
            count[0, row] = len(s.waypoints)
            cyl, sph = obstacle_inputs(s, CYLINDER_SLOTS, SPHERE_SLOTS)
            cylinders[:, row], spheres[:, row] = cyl.reshape(-1), sph.reshape(-1)
            workspace[:, row] = [*s.workspace.center, s.workspace.radius]
            goal[:, row] = s.waypoints[-1]
            grasps = np.asarray(s.grasp_rotations).reshape(n, 9)
            static[:, row] = np.hstack(
                [np.asarray(s.load_shares)[:, None], s.grasp_offsets, grasps]
            ).reshape(-1)
        xp, real = self.xp, self._real
        cols = self._on_device(np.array(rows))
        for target, values in (
            (self._waypoints, nav.reshape(m, -1).T),  # each column: (P, W) column-major
            (self._count, count),
            (self._cylinders, cylinders),
            (self._spheres, spheres),
            (self._workspace, workspace),
            (self._goal, goal),
            (self._static, static),
        ):
            target[:, cols] = xp.asarray(values, real)
        self._fill_padding()

    def _navigation_table_of(self, s: Scenario) -> np.ndarray:
        table = self.setup.navigation(s)
        if table is not None:
            return table
        if id(s) not in self._nav_tables:  # scenarios are kept in _scenarios: ids stay
            self._nav_tables[id(s)] = navigation_table(s)
        return self._nav_tables[id(s)]

    def _fill_padding(self) -> None:
        k = self.k
        for a in (
            self._static,
            self._goal,
            self._cylinders,
            self._spheres,
            self._workspace,
            self._waypoints,
            self._count,
        ):
            a[:, k:] = a[:, :1]

    def reset(
        self, rows: list[int], sim_seeds: list[int], conditions: list[Conditions] | None = None
    ) -> None:
        mismatch = current = None
        if conditions is not None:
            mismatch = [c.mismatch for c in conditions]
            current = [c.current for c in conditions]
        self.sim.reset(np.array(rows), sim_seeds, mismatch, current)
        self._a[:, self._on_device(np.array(rows))] = 0.0

    def step(self, tau: Any) -> Any:
        self._code = self.sim.step(tau)
        return self._code != OK

    def diverged_reasons(self, rows: list[int]) -> list[str]:
        codes = self._code[self._on_device(np.array(rows))]
        codes = codes if self.xp is np else self.xp.asnumpy(codes)
        return [DIVERGED_REASONS.get(int(c), "") for c in codes.tolist()]

    # -- the per-step kernels -----------------------------------------------------------
    def measure(self, ids: Any, q_noise: Any, zeta_noise: Any) -> None:
        x, n, m = self.sim.x, self.n, q_noise.shape[0]
        self._q_meas[:, ids] = q_noise.reshape(m, -1).T + x[: NQ * n, ids]
        self._zeta_meas[:, ids] = zeta_noise.reshape(m, -1).T + x[NQ * n : 2 * NQ * n, ids]

    def run_kinematics(
        self, ids: Any, action: Any, elapsed: Any, robots: Any, team: Any, measured: bool = True
    ) -> tuple:
        xp, n, k, s = self.xp, self.n, self.k, self.sim
        if action is not None:
            self._a[:, ids] = action.reshape(-1, n * NU).T
        self._time_fraction[0, ids] = elapsed
        self._robots[:, ids] = robots.reshape(-1, 2 * n).T
        self._team[:, ids] = team.T
        q, zeta, x_o = self._truth
        q_meas, zeta_meas = (self._q_meas, self._zeta_meas) if measured else (q, zeta)
        inputs = [
            self._a,
            q,
            zeta,
            q_meas,
            zeta_meas,
            x_o,
            s.grasp,
            self._static,
            self._robots,
            self._team,
            self._waypoints,
            self._count,
            self._goal,
            self._time_fraction,
            self._segments,
            self._cylinders,
            self._spheres,
            self._workspace,
        ]
        if self._wrench:  # the internal wrench's inputs but the grasp
            inputs += [s.x, s._tau, s._vc, s.parameters, s.object_parameters]
        if isinstance(ids, slice):
            out = self._call(self._kinematics, inputs, out=self._kin_out)
            m = k
        else:
            m = len(ids)
            cols = _padded_columns(ids, self._kinematics.padded(m), xp)
            out = self._call(self._kinematics, [xp.ascontiguousarray(a[:, cols]) for a in inputs])
            for full_out, part in zip(self._kin_out, out, strict=True):
                full_out[:, ids] = part[:, :m]
        f64 = np.float64
        obs = out[0][:, :m].reshape(n, OBSERVATION_SIZE, m).transpose(2, 0, 1).astype(f64)
        team = out[4][:, :m].astype(f64)
        g = out[2][:, :m].reshape(n, NK, m).transpose(2, 0, 1).astype(f64)
        cost = out[3][:, :m].reshape(n, ROBOT_SCALARS, m)[:, ROBOT_VIOLATED].T.astype(np.int64)
        robots = out[5][:, :m].reshape(n, 2, m).transpose(2, 0, 1).astype(f64)
        return obs, team, g, cost, robots

    def wrench_sq(self, sampled: Any) -> Any:
        sq = self._kin_out[6][0, : self.k].astype(np.float64)  # the step's evaluation's
        return self.xp.where(sampled, sq, 0.0)

    def object_pose(self, ids: Any) -> Any:
        n = self.n
        return self.sim.x[2 * NQ * n : 2 * NQ * n + 6, ids].T.astype(np.float64)

    def robots(self) -> tuple[Any, Any]:
        n, k, x = self.n, self.k, self.sim.x
        q = x[: NQ * n, :k].T.reshape(k, n, NQ).astype(np.float64)
        zeta = x[NQ * n : 2 * NQ * n, :k].T.reshape(k, n, NQ).astype(np.float64)
        return q, zeta

    def flat_state(self) -> Any:
        return self.sim.x[:, : self.k].T.astype(np.float64)

    # -- the priors on the device -------------------------------------------------------------
    def steady(self, raw: Any, ring: float) -> Any:
        if self._prior_kernels is None:
            return super().steady(raw, ring)
        return self._robot_columns(self._prior_kernels[0], raw, NU)

    def features(
        self, raw: Any, steady: Any, priors: Priors, ring: float, memory: Any = None
    ) -> Any:
        if self._prior_kernels is None:
            return super().features(raw, steady, priors, ring, memory)
        features = self._robot_columns(self._prior_kernels[1], raw, BASE_FEATURES)
        parts = [features, steady] if memory is None else [features, memory, steady]
        return self.xp.concatenate(parts, -1).astype(np.float32)

    def _robot_columns(self, kernel: Any, raw: Any, size: int) -> Any:
        """(m, N, size) float64: a prior's kernel over the m N robots' observations."""
        m = raw.shape[0]
        columns = self.xp.ascontiguousarray(raw.reshape(m * self.n, -1).T, self._real)
        out = self._call(kernel, [columns])[0]
        return out.T.reshape(m, self.n, size).astype(np.float64)


def _padded_columns(ids: Any, padded: int, xp: Any = np) -> Any:
    ids = xp.asarray(ids)
    if padded == len(ids):
        return ids
    return xp.concatenate([ids, xp.full(padded - len(ids), ids[0])])
