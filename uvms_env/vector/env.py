"""K cooperative-transport environments stepped together: the single environment, batched.

    from uvms_env.vector import VectorEnv
    venv = VectorEnv("paper", num_envs=256, dtype="float32")
    obs, infos = venv.reset(seed=0)                  # obs (K, N, 79) float32
    obs, reward, terminated, truncated, infos = venv.step(actions)   # actions (K, N, 8)

Environment k is ``parallel_env(scenario, **overrides)`` reset with seed ``seed + k``
(``reset(seed=[s_0, ...])``: one seed each), stepped with ``actions[k]``: in float64 the
same observations, rewards, constraint values, terminations and metrics step for step
(the tests hold it to 1e-9, automatic resets included). The class docstring lists what
differs and what is returned.

One step is a few compiled calls over all K environments, with the environment index
innermost (``uvms_env.vector.kernels``: SIMD lanes, threads over cores): the period
step of the truth simulator (``BatchedSimulator``), the kinematics kernel of the single
environment (``env.kinematics.team_function``: observations, pose estimates, constraint
values, team reductions), the navigation twist at each robot's active waypoint
(``navigation.parametric``) and, when sampled, the internal wrench (the chain's own
function). The rest (sequencing, reward, termination, metrics) is array code over K
(``uvms_env.env.task.Task``, the code the single environment runs with K = 1). Python
runs per environment only where an environment's own random generator must
be drawn from (sensor noise, ocean current: a loop over K when they are switched on, so
that every draw is the single environment's) and for environments whose episode ended
(their metrics dict and their reset).

**GPU** (``backend="cuda"``, ``device=`` a GPU index): the same class with CuPy arrays in
place of numpy ones and the same CasADi functions compiled as CUDA kernels
(``kernels_cuda``; a_ss and the features too). States, observations, rewards, constraint
values and the sequencing stay on the GPU; ``reset``/``step``/``state`` return torch
tensors there (DLPack, no copy) and ``step`` takes torch CUDA tensors (or CuPy or numpy
arrays). Per step the host reads a few flags (any refusal, any episode ended); the
environments that ended come to the host for their metrics dicts and their resets (the
truth-model draws of each environment's own generator). ``device="cpu"`` compiles the
same kernel source for the host and runs this path on numpy arrays: how the tests check
it, to rounding against the CPU backend, on machines without a GPU.

May import: numpy, gymnasium (spaces), torch (only to return tensors on the CUDA
backend), ``uvms_env`` below ``vector`` and the ``env`` modules whose kernels and
constants it batches.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from uvms_env.dynamics import NQ, NU
from uvms_env.env.kinematics import (
    BATCH_CYLINDERS,
    BATCH_SPHERES,
    NK,
    obstacle_inputs,
    segment_inputs,
    team_function,
)
from uvms_env.env.observation import (
    FAR_OBSTACLE,
    NOISE_STD_Q,
    NOISE_STD_ZETA,
    OBSERVATION_LAYOUT,
    OBSERVATION_SIZE,
    OBSERVATION_STRUCTURE,
)
from uvms_env.env.parallel import (
    ACTION_KINDS,
    CONSTRAINT_MODES,
    RESET_SEED,
    _make_scenario,
    observation_space,
    priors_of,
    split_keywords,
    task_of,
)
from uvms_env.env.priors import BASE_FEATURES, prior_functions, steady_inputs
from uvms_env.env.reward import RewardWeights
from uvms_env.env.task import TaskArrays
from uvms_env.navigation.parametric import parametric_twist_function
from uvms_env.scenarios import Scenario
from uvms_env.scenarios.overrides import Option
from uvms_env.sim.current import OceanCurrent
from uvms_env.vector.bank import NAV_PARAMETERS, SEEDED_FAMILIES, GeometryBank, navigation_table
from uvms_env.vector.kernels import BatchedFunction, available_cores
from uvms_env.vector.simulator import BACKENDS, ENVELOPE, INACCURATE, OK, BatchedSimulator

ALL = slice(None)  # every environment, as an index (also the task's)
VECTOR_OPTIONS: dict[str, Option] = {
    "geometry_pool": Option(
        "int", "seeded families: episodes cycle through this many bank seeds", low=1, optional=True
    ),
}
DIVERGED_REASONS = {
    INACCURATE: (
        "a 1/16 part of the period still drifted from the grasps beyond the error "
        "control's tolerance"
    ),
    ENVELOPE: "a speed went beyond the model's physical envelope (SPEED_LIMITS)",
}
_WAYPOINT = OBSERVATION_STRUCTURE["waypoint"]
_NAV = OBSERVATION_STRUCTURE["nav_velocity"]
_SEED_LIMIT = 2**63


class VectorEnv:
    """K environments of one scenario family and team size, stepped together.

    Construct: ``VectorEnv(scenario="paper", num_envs=1, backend="cpu", dtype="float64",
    threads=None, lanes=None, device=0, **overrides)``; the overrides are every keyword of
    ``parallel_env`` (scenario overrides and environment options, with the same checks)
    plus ``geometry_pool``. ``backend="cuda"``: on GPU ``device`` (module docstring); the
    arrays below are then torch tensors on that device, except the per-environment
    objects of ``infos`` (``episode_end``, ``metrics``, ``diverged_reason``) and
    ``episode_seed``, which stay numpy.

    | call | returns |
    |---|---|
    | `reset(seed=None)` | `obs` (K, N, 79) float32, `infos` (dict) |
    | `step(actions)`: (K, N, 8) in [-1, 1] | `obs`, `reward`, `terminated`, `truncated`, `infos` |
    | `state()` | (K, 20 N + 19) float32: each environment's `parallel_env.state()` |

    **Seeding.** `reset(seed=s)`: environment k starts as `parallel_env(...).reset(seed=s + k)`;
    `reset(seed=[s_0, ..., s_{K-1}])` gives each its seed; `reset()` continues every
    environment's own sequence, as the single env's `reset()` does. For the seeded
    families ("random", "short") environment k then has geometry `s + k`, built once
    and kept on disk by `uvms_env.vector.bank` (`python -m uvms_env.vector.build_bank` builds
    them ahead of time; a first build costs ~0.5 s per random geometry). The first
    `reset()` without a seed uses the `seed` override (or 0) as `s`.

    **Automatic reset** (same step, the Gymnasium `SAME_STEP` / SB3 convention): an
    environment whose episode ends is reset inside `step`; the returned `obs` row is the
    new episode's first observation and `infos["final_observation"]` holds the last
    one. By default the new episode is the single env's `reset()`: the same geometry,
    the next draws of the environment's own generator. With `geometry_pool=P` (seeded
    families; training), episode e of environment k (e = 0 after `reset(seed=s)`) is
    instead `reset(seed=(s + k + K e) % P)`: every episode a geometry from the bank's
    first P seeds.

    **Infos** (arrays over environments; a key is present every step):

    | key | shape | meaning |
    |---|---|---|
    | constraint_values | (K, N, 8 + E) | g <= 0 holds: `CONSTRAINTS`, then E extra ones |
    | cost | (K, N) | violated constraints per robot |
    | reward_terms | dict name -> (K,) | the terms of the shared reward (extra terms last) |
    | success | (K,) bool | the episode succeeded this step |
    | episode_end | (K,) object | "" or success, collision, constraint, diverged, max_cycles |
    | final_observation | (K, N, 79) | last observation of the envs that ended (else zeros) |
    | final_state | (K, 20 N + 19) or None | `state()` before the resets, when an env ended |
    | metrics | (K,) object | the ended episodes' metrics (`uvms_env.env.metrics`) or None |
    | diverged_reason | (K,) object | why a step was refused ("" elsewhere) |

    **Extensions**: `extra_reward_terms` and `extra_constraints` as in `parallel_env`; the
    functions receive the K environments' arrays (CuPy ones on a GPU) and `xp`.

    **Float32** (`dtype="float32"`): every compiled call in single precision, rewards and
    metrics in float64 from its results; the fast mode. Its deviation from float64 is
    measured in the tests and the README.

    **Differences from K single envs.** No rendering. Per-environment geometries share
    the team size, the object, the period and the substeps (always so within a family
    and team size). `diverged_reason` names the kind of refusal but not the time and
    value. Threads: `threads` (default: every core this process may use).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": "same_step"}

    def __init__(
        self,
        scenario: str | Scenario = "paper",
        num_envs: int = 1,
        backend: str = "cpu",
        dtype: str = "float64",
        threads: int | None = None,
        lanes: int | None = None,
        device: int | str = 0,
        **overrides: Any,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.backend = backend
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer):
            raise TypeError(f"num_envs must be an int >= 1, got {num_envs!r}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        overrides, options, vector = split_keywords(overrides, VECTOR_OPTIONS, "vector")
        self.num_envs = k = int(num_envs)
        self.dtype = dtype
        self.threads = int(threads) if threads is not None else available_cores()
        self.constraint_mode = options.get("constraint_mode", "penalize")
        assert self.constraint_mode in CONSTRAINT_MODES
        self.reward_weights = RewardWeights.from_mapping(options.get("reward_weights"))
        self.internal_wrench_every = options.get("internal_wrench_every", 1)
        self.priors = priors_of(options)
        self.geometry_pool: int | None = vector.get("geometry_pool")
        self._extensions = {k: options.get(k) for k in ("extra_reward_terms", "extra_constraints")}

        if isinstance(scenario, Scenario):
            if "n_agents" in overrides:
                raise ValueError("n_agents cannot be overridden on a built Scenario")
            from uvms_env.scenarios import replace

            base = replace(scenario, **overrides) if overrides else scenario
            self.family: str | None = None
        elif isinstance(scenario, str):
            from uvms_env.scenarios import FAMILIES

            if scenario not in FAMILIES:
                raise ValueError(f"unknown scenario family {scenario!r}; known: {list(FAMILIES)}")
            self.family = scenario
            base = None
        else:
            raise ValueError(f"scenario must be a family name or a Scenario, got {scenario!r}")
        self._seeded = self.family in SEEDED_FAMILIES and options.get("reseed_geometry", True)
        if self.geometry_pool is not None and not self._seeded:
            raise ValueError(
                "geometry_pool needs a seeded family (random, short) with reseed_geometry"
            )
        self._overrides = overrides
        self._first_seed = int(overrides.get("seed") or 0)
        self._bank: GeometryBank | None = None
        if self._seeded:
            assert self.family is not None
            self._bank = GeometryBank(self.family, int(overrides.get("n_agents", 2)))
            base = self._bank.get(self._first_seed).scenario_with(overrides)
        elif base is None:
            assert self.family is not None
            base = _make_scenario(self.family, overrides)
        self._base = base
        self._ring = base.object_ring_radius  # one object per VectorEnv (see Differences)
        self.n = n = base.n_agents
        max_cycles = options.get("max_cycles")
        self.max_cycles = int(base.max_steps) if max_cycles is None else int(max_cycles)
        self.possible_agents = [f"uvms_{i}" for i in range(n)]
        self.agents = list(self.possible_agents)
        self.single_observation_space = observation_space(self.priors)
        self.single_action_space = spaces.Box(-1.0, 1.0, (NU,), np.float32)
        self.observation_structure = dict(OBSERVATION_STRUCTURE)

        # -- compiled calls -----------------------------------------------------------
        self.sim = BatchedSimulator(base, k, backend, dtype, self.threads, lanes, device)
        self.xp = xp = self.sim.xp  # numpy, or CuPy on a GPU: the per-step arrays live there
        self.device = device if backend == "cuda" else "cpu"
        self._lanes = self.sim._fn.lanes if backend == "cpu" else 1
        self._kp = kp = self.sim._kp
        self._real = real = self.sim._real
        self._noisy = base.sensor_noise > 0
        segments = self.sim.object.segments
        self._n_seg = len(segments)
        self._kinematics = self._kernel(
            team_function(
                n,
                self._n_seg,
                BATCH_CYLINDERS,
                BATCH_SPHERES,
                OBSERVATION_LAYOUT,
                tuple(FAR_OBSTACLE),
                self._noisy,
            )
        )
        self._navigation = self._kernel(parametric_twist_function(BATCH_CYLINDERS, BATCH_SPHERES))
        self._wrench = (
            self._kernel(self.sim.chain.internal_wrench) if self.internal_wrench_every > 0 else None
        )
        # the priors' a_ss and features: host calls on the CPU backend (the single env's),
        # kernels of the same CasADi expressions on the GPU, over the K N robots' columns
        self._prior_kernels = (
            prior_functions(self._ring) if backend == "cuda" and self.priors.needs_steady else None
        )
        if self._prior_kernels is not None:
            self._prior_kernels = tuple(self._kernel(f) for f in self._prior_kernels)

        # -- per-environment inputs of the kinematics kernel, (nnz, K padded) ---------
        z = lambda rows: xp.zeros((rows, kp), real)  # noqa: E731
        self._a = z(NU * n)
        self._q_meas, self._zeta_meas = z(NQ * n), z(NQ * n)
        self._static, self._waypoint_in = z(13 * n), z(6 * n)
        self._goal, self._time_fraction = z(6), z(1)
        self._segments = z(6 * self._n_seg)
        self._cylinders, self._spheres = z(4 * BATCH_CYLINDERS), z(5 * BATCH_SPHERES)
        self._workspace = z(4)
        self._segments[:] = xp.asarray(segment_inputs(segments, self._n_seg).reshape(-1, 1))
        sig = self._kinematics.signature
        self._kin_out = [xp.zeros((m, kp), real) for m in sig.nnz_out]

        # -- per-environment episode data (float64; where the step runs) -----------------
        self.scenarios: list[Scenario] = [base] * k
        self._geometry_set = np.zeros(k, bool)
        self._by_seed: dict[int, Scenario] = {}  # geometry seed -> scenario with overrides
        self._nav_tables: dict[int, np.ndarray] = {}  # id(scenario) -> navigation table
        w_max = 3 if self.family == "random" else len(base.waypoints)
        self._w_max = w_max
        self._nav_table = xp.zeros((k, w_max, NAV_PARAMETERS))
        # the task's rules and episode bookkeeping over the K environments (their arrays)
        self.task = task_of(base, self, k, w_max, xp)
        # episode bookkeeping of the resets (host: read in Python per ended environment)
        self._episode = np.zeros(k, np.int64)
        self._episode_base = np.zeros(k, np.int64)
        self._seeders = [np.random.default_rng(self._first_seed + i) for i in range(k)]
        self._seeds_now = np.full(k, -1)  # the seeds of the last seeded reset (-1: none)
        self._noise_rngs = [np.random.default_rng(0) for _ in range(k)]
        self._currents = [
            OceanCurrent(self.sim.uvms.params.currents[base.current]) for _ in range(k)
        ]
        self._current_on = self._currents[0].preset.max > 0.0
        # the noise scales where the noise is scaled: on the device (CuPy takes no numpy
        # operand in its arithmetic)
        self._noise_q = xp.asarray(base.sensor_noise * NOISE_STD_Q)
        self._noise_zeta = xp.asarray(base.sensor_noise * NOISE_STD_ZETA)
        self._obs = xp.zeros((k, n, OBSERVATION_SIZE), np.float32)
        # a_ss of the robots' current observations, kept beside them when the priors use it
        self._steady = xp.zeros((k, n, NU))
        self._started = False
        # ``command_filter(raw_obs, commands, first)`` -> commands: replaces each step's
        # normalized inputs before they reach the simulator (a safety filter in the
        # training loop); raw_obs (K, N, 79) are the observations the actions answer,
        # commands (K, N, 8) float64 what the action mode made of them, first (K,) bool
        # marks the environments whose episode starts with this step. None: no filter.
        self.command_filter: Any = None
        self._tau_max = xp.asarray(self.sim.tau_max)  # the saturations, where the step runs
        self._set_geometry(np.arange(k), [base] * k)

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

    def _host(self, a: Any) -> np.ndarray:
        """A numpy copy of a step array, for Python code and the caller's host data."""
        return np.asarray(a) if self.xp is np else self.xp.asnumpy(a)

    def _export(self, a: Any) -> Any:
        """What ``reset``/``step`` return for a step array: numpy on the CPU backend,
        torch tensors on the CUDA backend's device (zero-copy through DLPack)."""
        if self.backend == "cpu" or a is None:
            return a
        import torch

        if self.xp is np:  # the emulated device: torch on the host
            return torch.from_numpy(np.ascontiguousarray(a))
        return torch.from_dlpack(a)

    # -- spaces and views ---------------------------------------------------------------
    @property
    def observation_space(self) -> spaces.Box:
        one = self.single_observation_space
        shape = (self.num_envs, self.n, *one.shape)
        return spaces.Box(
            np.broadcast_to(one.low, shape), np.broadcast_to(one.high, shape), shape, np.float32
        )

    @property
    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.num_envs, self.n, NU), np.float32)

    @property
    def scenario(self) -> Scenario:
        """Environment 0's scenario (every environment's: ``scenarios``)."""
        return self.scenarios[0]

    def state(self) -> Any:
        """(K, 20 N + 19) float32: the true state, the team's waypoint and the time
        fraction of every environment, as ``parallel_env.state()`` (a torch tensor on the
        CUDA backend)."""
        return self._export(self._state())

    def _state(self) -> Any:
        xp, k = self.xp, self.num_envs
        x = self.sim.x[:, :k].T.astype(np.float64)
        wp = self.task.team_waypoint
        full = xp.concatenate([x, wp, self.task.time_fraction()[:, None]], axis=1)
        return full.astype(np.float32)

    # -- episodes -----------------------------------------------------------------------
    def reset(
        self, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode in every environment (see Seeding; ``options`` is unused)."""
        k = self.num_envs
        if seed is None and not self._started:
            seed = self._first_seed
        if seed is None and self.geometry_pool is not None:  # every env: its next episode
            self._autoreset(np.arange(k))
            return self._export(self._view(ALL)), {"episode_seed": self._pool_seeds(np.arange(k))}
        if seed is not None:
            seeds = self._seed_list(seed)
            self._episode_base[:] = seeds
            self._episode[:] = 0
            if self.geometry_pool is not None:
                seeds = self._pool_seeds(np.arange(k)).tolist()
            self._seeders = [np.random.default_rng(s) for s in seeds]
            self._seeds_now = np.array(seeds)
            if self._seeded:
                self._set_geometry(np.arange(k), self._geometries(seeds))
        self._started = True
        self._reset_envs(np.arange(k))
        return self._export(self._view(ALL)), {"episode_seed": self._seeds_now.copy()}

    def _seed_list(self, seed: int | Sequence[int]) -> list[int]:
        k = self.num_envs
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            base = RESET_SEED.check("seed", seed)
            return [base + i for i in range(k)]
        try:
            seeds = list(seed)  # type: ignore[arg-type]
        except TypeError:
            raise TypeError(f"seed must be None, an int >= 0 or {k} ints, got {seed!r}") from None
        if len(seeds) != k:
            raise ValueError(f"reset got {len(seeds)} seeds for {k} environments")
        return [RESET_SEED.check(f"seed of environment {i}", s) for i, s in enumerate(seeds)]

    def _geometries(self, geometry_seeds: Sequence[int]) -> list[Scenario]:
        assert self._bank is not None
        out = []
        for seed in geometry_seeds:
            if seed not in self._by_seed:
                self._by_seed[seed] = self._bank.get(seed).scenario_with(self._overrides)
            out.append(self._by_seed[seed])
        return out

    def _navigation_table_of(self, s: Scenario) -> np.ndarray:
        if self._bank is not None and s.seed is not None:
            return self._bank.get(s.seed).navigation
        if id(s) not in self._nav_tables:  # scenarios are kept in self.scenarios: ids stay
            self._nav_tables[id(s)] = navigation_table(s)
        return self._nav_tables[id(s)]

    def _set_geometry(self, ids: np.ndarray, scenarios: Sequence[Scenario]) -> None:
        """Environments ``ids`` take these scenarios' geometries (kernel inputs, waypoints,
        navigation parameters, simulator grasps). Same-object checks: the simulator's."""
        n, w_max = self.n, self._w_max
        changed = [
            (i, s)
            for i, s in zip(ids.tolist(), scenarios, strict=True)
            if not (self.scenarios[i] is s and self._geometry_set[i])
        ]
        if not changed:
            return
        m = len(changed)
        # gathered on the host, written with one copy per array (one transfer on a GPU)
        waypoints, nav = np.zeros((m, w_max, 6)), np.zeros((m, w_max, NAV_PARAMETERS))
        count, obstacles = np.zeros(m, np.int64), np.zeros(m, bool)
        cylinders, spheres = np.zeros((4 * BATCH_CYLINDERS, m)), np.zeros((5 * BATCH_SPHERES, m))
        workspace, goal, static = np.zeros((4, m)), np.zeros((6, m)), np.zeros((13 * n, m))
        for row, (i, s) in enumerate(changed):
            if s.n_agents != n:
                raise ValueError(f"environment {i}: {s.n_agents} agents, the batch has {n}")
            w = len(s.waypoints)
            if w > w_max:
                raise ValueError(f"environment {i}: {w} waypoints, the batch has room for {w_max}")
            self.sim.set_scenario([i], s)
            self.scenarios[i] = s
            self._geometry_set[i] = True
            waypoints[row, :w] = s.waypoints
            count[row] = w
            nav[row, :w] = self._navigation_table_of(s)
            obstacles[row] = bool(s.obstacles)
            cyl, sph = obstacle_inputs(s, BATCH_CYLINDERS, BATCH_SPHERES)
            cylinders[:, row], spheres[:, row] = cyl.reshape(-1), sph.reshape(-1)
            workspace[:, row] = [*s.workspace.center, s.workspace.radius]
            goal[:, row] = s.waypoints[-1]
            static[:, row] = np.hstack(
                [
                    np.asarray(s.load_shares)[:, None],
                    s.grasp_offsets,
                    np.asarray(s.grasp_rotations).reshape(n, 9),
                ]
            ).reshape(-1)
        xp, real = self.xp, self._real
        cols = self._on_device(np.array([i for i, _ in changed]))
        self.task.set_geometry(cols, waypoints, count, obstacles)
        self._nav_table[cols] = xp.asarray(nav)
        for target, rows in (
            (self._cylinders, cylinders),
            (self._spheres, spheres),
            (self._workspace, workspace),
            (self._goal, goal),
            (self._static, static),
        ):
            target[:, cols] = xp.asarray(rows, real)
        self._fill_padding()

    def _fill_padding(self) -> None:
        k = self.num_envs
        for a in (
            self._static,
            self._goal,
            self._cylinders,
            self._spheres,
            self._workspace,
            self._waypoint_in,
        ):
            a[:, k:] = a[:, :1]

    def _reset_envs(self, ids: np.ndarray) -> None:
        """The single env's ``reset()`` for environments ``ids``: new draws from each one's
        generator, start state, sequencers, metrics, first observation (into
        ``self._obs``)."""
        sim_seeds = []
        for i in ids.tolist():
            rng = np.random.default_rng(self._seeders[i].integers(_SEED_LIMIT))
            sim_seeds.append(int(rng.integers(_SEED_LIMIT)))
            self._noise_rngs[i] = rng
        generators = self.sim.reset(ids, sim_seeds)
        for i, gen in zip(ids.tolist(), generators, strict=True):
            self._currents[i].reset(gen)
        if len(ids) == self.num_envs:  # all of them: the kernels' full path, no gathering
            ids = slice(0, self.num_envs)
        ids = self._on_device(ids)
        self.task.reset(ids)
        self._copy_robot_waypoints(ids)
        self._a[:, ids] = 0.0
        self._evaluate(ids)
        self.task.start(ids, self._object_pose(ids))

    def _copy_robot_waypoints(self, ids: Any) -> None:
        """The robots' active waypoints of ``ids`` into the kinematics kernel's inputs."""
        wp = self.task.robot_waypoint[ids]
        self._waypoint_in[:, ids] = wp.reshape(wp.shape[0], self.n * 6).T
        self._waypoint_in[:, self.num_envs :] = self._waypoint_in[:, :1]  # padding lanes

    # -- stepping -------------------------------------------------------------------------
    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("step() called before reset()")
        xp, k, n = self.xp, self.num_envs, self.n
        a = self._check_actions(actions)
        current = None
        if self._current_on:
            current = xp.asarray(np.array([c.step(self._base.period) for c in self._currents]))
        # numpy's functions dispatch to CuPy's for CuPy arrays (NEP 18): one formula
        command = self.priors.command(self._obs, a, self._ring, self._steady)
        if self.command_filter is not None:
            command = self.command_filter(self._obs, command, self.task.steps == 0)
        code = self.sim.step(command * self._tau_max, current)
        task = self.task
        task.max_cycles = self.max_cycles  # an attribute a user may change
        diverged = code != OK
        sampled = task.tick(diverged)
        self._a[:, :k] = a.reshape(k, n * NU).T
        all_envs = slice(0, k)  # the simulator's and kernels' arrays have padding lanes
        self._evaluate(all_envs)
        team = self._kin_out[4][:, :k].astype(np.float64)
        x_o = self._object_pose(all_envs)
        wrench_sq = None
        if sampled is not None and sampled.any():
            wrench_sq = xp.where(sampled, self._internal_wrench_sq(), 0.0)
        g = self._kin_out[2][:, :k].reshape(n, NK, k).transpose(2, 0, 1).astype(np.float64)
        cost = self._kin_out[3][:, :k].reshape(n, 6, k)[:, 4].T.astype(np.int64)
        state = self._task_arrays(x_o, a) if task.extended else None
        out = task.step(x_o, team, g, cost, diverged, sampled, wrench_sq, state)
        reward, terms, success = out.reward, out.terms, out.success
        ended = out.terminated | out.truncated
        final_obs = xp.zeros((k, n, *self.single_observation_space.shape), np.float32)
        infos: dict[str, Any] = {
            "constraint_values": out.constraint_values,
            "cost": out.cost,
            "reward_terms": terms,
            "success": success,
            "episode_end": np.full(k, "", dtype=object),
            "final_observation": final_obs,
            "final_state": None,
            "metrics": np.full(k, None, dtype=object),
            "diverged_reason": np.full(k, "", dtype=object),
        }
        if bool(diverged.any()):
            refused = np.flatnonzero(self._host(diverged))
            for i, c in zip(refused.tolist(), self._host(code)[refused].tolist(), strict=True):
                infos["diverged_reason"][i] = DIVERGED_REASONS[int(c)]
        if bool(ended.any()):
            # the ended environments' flags and poses on the host, in one transfer each
            done = np.flatnonzero(self._host(ended))
            on = self._on_device(done)
            infos["final_observation"][on] = self._view(on)
            infos["final_state"] = self._state()  # before the reset, for central critics
            infos["episode_end"][done] = task.end_kinds(on, out, diverged)
            infos["metrics"][done] = task.results(on, x_o[on], success[on])
            self._autoreset(done)
        if self.backend == "cuda":
            for key in ("constraint_values", "cost", "success", "final_observation", "final_state"):
                infos[key] = self._export(infos[key])
            infos["reward_terms"] = {
                name: self._export(xp.broadcast_to(v, (k,)).copy()) for name, v in terms.items()
            }
        return (
            self._export(self._view(ALL)),
            self._export(reward),
            self._export(out.terminated),
            self._export(out.truncated),
            infos,
        )

    def _task_arrays(self, x_o: Any, action: Any) -> TaskArrays:
        """What the extra reward terms and constraints see, over the K environments."""
        n, k, task = self.n, self.num_envs, self.task
        x = self.sim.x
        q = x[: NQ * n, :k].T.reshape(k, n, NQ).astype(np.float64)
        zeta = x[NQ * n : 2 * NQ * n, :k].T.reshape(k, n, NQ).astype(np.float64)
        return TaskArrays(x_o, q, zeta, action, task.team_waypoint, task.goal, task.steps)

    def restart(self, env_ids: Any) -> np.ndarray:
        """End the episodes of ``env_ids`` where they stand and start their next ones, as the
        automatic reset does (a partial reset, e.g. for TorchRL's ``_reset`` mask); returns
        their first observations (len(env_ids), N, 79). The other environments go on."""
        if not self._started:
            raise RuntimeError("restart() called before reset()")
        ids = np.unique(np.asarray(env_ids, dtype=np.int64).reshape(-1))
        if len(ids) and (ids[0] < 0 or ids[-1] >= self.num_envs):
            raise ValueError(f"env_ids must lie in 0..{self.num_envs - 1}, got {env_ids!r}")
        if len(ids):
            self._autoreset(ids)
        return self._export(self._view(self._on_device(ids)))

    def _autoreset(self, ids: np.ndarray) -> None:
        self._episode[ids] += 1
        if self.geometry_pool is not None:
            seeds = self._pool_seeds(ids).tolist()
            for i, s in zip(ids.tolist(), seeds, strict=True):
                self._seeders[i] = np.random.default_rng(s)
            self._set_geometry(ids, self._geometries(seeds))
        self._reset_envs(ids)

    def _view(self, ids: Any) -> Any:
        """A copy of the current observations of ``ids`` in the observation mode."""
        if self.priors.observation_mode == "raw":
            return self._obs[ids].copy()
        if self._prior_kernels is None:
            return self.priors.observe(self._obs[ids], self._ring, self._steady[ids])
        raw = self._obs[ids]
        features = self._robot_columns(self._prior_kernels[1], raw, BASE_FEATURES)
        return self.xp.concatenate([features, self._steady[ids]], -1).astype(np.float32)

    def _robot_columns(self, kernel: Any, raw: Any, size: int) -> Any:
        """(m, N, size) float64: a prior's kernel over the m N robots' observations."""
        m = raw.shape[0]
        columns = self.xp.ascontiguousarray(raw.reshape(m * self.n, -1).T, self._real)
        out = self._call(kernel, [columns])[0]
        return out.T.reshape(m, self.n, size).astype(np.float64)

    def _pool_seeds(self, ids: np.ndarray) -> np.ndarray:
        """The reset seeds of the current episodes of ``ids`` with a geometry pool."""
        assert self.geometry_pool is not None
        raw = self._episode_base[ids] + self.num_envs * self._episode[ids]
        return raw % self.geometry_pool

    def _as_array(self, actions: Any) -> Any:
        """Actions as the step's array type: numpy, or on the GPU without a copy where they
        are there already (torch CUDA tensors and CuPy arrays, through DLPack)."""
        xp = self.xp
        is_torch = type(actions).__module__.startswith("torch")
        if xp is np:
            return np.asarray(actions.detach().cpu() if is_torch else actions)
        if is_torch and actions.is_cuda:
            return xp.from_dlpack(actions.detach())
        return xp.asarray(actions.detach().cpu().numpy() if is_torch else actions)

    def _check_actions(self, actions: Any) -> Any:
        xp, k, n = self.xp, self.num_envs, self.n
        try:
            a = self._as_array(actions)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions must be an array of shape ({k}, {n}, {NU})") from exc
        if a.shape != (k, n, NU):
            hint = f" (num_envs is {k})" if a.ndim == 3 and a.shape[0] != k else ""
            raise ValueError(f"actions must have shape ({k}, {n}, {NU}), got {a.shape}{hint}")
        if a.dtype.kind not in ACTION_KINDS:
            raise ValueError(
                f"actions must be float or int (not bool, complex, str or object), got {a.dtype}"
            )
        a = a.astype(np.float64, copy=False)
        if not bool(xp.isfinite(a.sum())):
            env, robot, _ = self._host(xp.argwhere(~xp.isfinite(a))[0]).tolist()
            raise ValueError(
                f"action of environment {env}, agent {self.possible_agents[robot]!r} contains "
                "NaN or inf"
            )
        return a

    # -- the per-step kernels ---------------------------------------------------------------
    def _evaluate(self, ids: Any) -> None:
        """Measure, run the kinematics kernel, note the state metrics, sequence each robot's
        waypoints, add the navigation twist; the observations land in ``self._obs[ids]``."""
        xp, n, k = self.xp, self.n, self.num_envs
        full = isinstance(ids, slice)
        task = self.task
        self._time_fraction[0, ids] = task.time_fraction(ids)
        x = self.sim.x
        q, zeta = x[: NQ * n], x[NQ * n : 2 * NQ * n]
        if self._noisy:
            self._measure(np.arange(k) if full else self._host(ids), q, zeta)
        inputs = [
            self._a,
            q,
            zeta,
            self._q_meas,
            self._zeta_meas,
            x[2 * NQ * n : 2 * NQ * n + 6],
            self.sim.grasp,
            self._static,
            self._waypoint_in,
            self._goal,
            self._time_fraction,
            self._segments,
            self._cylinders,
            self._spheres,
            self._workspace,
        ]
        if full:
            out = self._call(self._kinematics, inputs, out=self._kin_out)
            m = k
        else:
            m = len(ids)
            cols = _padded_columns(ids, self._kinematics.padded(m), xp)
            out = self._call(self._kinematics, [xp.ascontiguousarray(a[:, cols]) for a in inputs])
            for full_out, part in zip(self._kin_out, out, strict=True):
                full_out[:, ids] = part[:, :m]
        obs_rows, pose_rows, team = out[0][:, :m], out[1][:, :m], out[4][:, :m]
        team = team.astype(np.float64)
        task.observe(ids, team)
        obs = obs_rows.reshape(n, OBSERVATION_SIZE, m).transpose(2, 0, 1).astype(np.float64)
        pose = pose_rows.reshape(n, 6, m).transpose(2, 0, 1).astype(np.float64)  # (m, N, 6)
        # each robot's own sequencing, on its own estimate
        if task.advance_robots(ids, pose, team):
            self._copy_robot_waypoints(ids)
        env_rows = xp.arange(k)[ids]
        index = task.robot_index[ids]
        obs[:, :, _WAYPOINT] = task.robot_waypoint[ids]
        obs[:, :, _NAV] = self._navigation_twist(env_rows, index, pose)
        self._obs[ids] = obs
        if self._prior_kernels is not None:  # a_ss on the device, from the same expression
            self._steady[ids] = self._robot_columns(self._prior_kernels[0], self._obs[ids], NU)
        elif self.priors.needs_steady:  # from the float32 observations, as the single env
            self._steady[ids] = steady_inputs(self._obs[ids], self._ring)

    def _measure(self, ids: np.ndarray, q: np.ndarray, zeta: np.ndarray) -> None:
        """Sensor noise from each environment's generator (the single env's draws)."""
        n = self.n
        noise = np.stack([self._noise_rngs[i].standard_normal((2, n, NQ)) for i in ids.tolist()])
        noise = self.xp.asarray(noise)  # drawn on the host: each environment's own generator
        qn = noise[:, 0] * self._noise_q  # (m, N, 10)
        zn = noise[:, 1] * self._noise_zeta
        on = self._on_device(ids)
        self._q_meas[:, on] = qn.reshape(len(ids), -1).T + q[:, on]
        self._zeta_meas[:, on] = zn.reshape(len(ids), -1).T + zeta[:, on]

    def _navigation_twist(
        self, env_rows: np.ndarray, index: np.ndarray, pose: np.ndarray
    ) -> np.ndarray:
        """(m, N, 6): each robot's navigation twist towards its active waypoint at its own
        estimate: one batched call over the m N robots."""
        xp = self.xp
        m, n = index.shape
        cols = m * n
        cp = self._navigation.padded(cols)
        params = self._nav_table[env_rows[:, None], index].reshape(cols, NAV_PARAMETERS)
        x = pose.reshape(cols, 6)
        if cp > cols:
            params = xp.concatenate([params, xp.repeat(params[:1], cp - cols, axis=0)])
            x = xp.concatenate([x, xp.repeat(x[:1], cp - cols, axis=0)])
        x_in = xp.ascontiguousarray(x.T, self._real)
        p = xp.ascontiguousarray(params.T, self._real)
        bounds = np.cumsum([0, *self._navigation.signature.nnz_in[1:]]).tolist()
        inputs = [x_in] + [xp.ascontiguousarray(p[a:b]) for a, b in itertools.pairwise(bounds)]
        twist = self._call(self._navigation, inputs)[0]
        return twist[:, :cols].T.reshape(m, n, 6)

    def _internal_wrench_sq(self) -> np.ndarray:
        """(K,) squared Frobenius norm of the internal wrench after the step."""
        assert self._wrench is not None
        s = self.sim
        out = self._call(
            self._wrench, [s.x, s._tau, s._vc, s.parameters, s.object_parameters, s.grasp]
        )[0][:, : self.num_envs].astype(np.float64)
        return self.xp.einsum("ij,ij->j", out, out)

    def _object_pose(self, ids: Any) -> np.ndarray:
        n = self.n
        return self.sim.x[2 * NQ * n : 2 * NQ * n + 6, ids].T.astype(np.float64)

    def close(self) -> None:
        """Nothing to release (no windows, no processes); for the Gymnasium contract."""


def _padded_columns(ids: Any, padded: int, xp: Any = np) -> Any:
    ids = xp.asarray(ids)
    if padded == len(ids):
        return ids
    return xp.concatenate([ids, xp.full(padded - len(ids), ids[0])])
