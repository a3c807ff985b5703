"""The code that drives the task, written once for one environment and for K.

``EnvCore`` runs the flow of an episode around the task's rules (``uvms_env.task.rules``) on
a physics engine (the ``Engine`` protocol: ``ScalarEngine`` for ``parallel_env``, batch
shape B = (); ``BatchedEngine`` for ``VectorEnv``, B = (K,)). The environments only turn
their APIs into calls here. Reference: docs/environment.md, "The task and its driver".

Indices: ``ids`` index the engine's and the task's arrays (``...`` for one environment; a
slice or an index array of ``xp`` for K), ``rows`` are the same environments as host
ints, for what Python does per environment (each one's random generators).

The acoustic channel (``uvms_env.robot.channel``, ``comm=``) runs here too, once for both:
with one, an action is B + (N, 8 + 1 + D) (inputs, send flag, message), the channel takes
the message part of each step and ``view`` appends each robot's inbox.

May import: numpy and the ``env`` modules of the task's rules, its options, the
observation's layout and the channel.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from uvms_env.dynamics import NQ, NU
from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.env.options import EnvSetup
from uvms_env.robot.channel import Channel
from uvms_env.robot.memory import Memory
from uvms_env.robot.observation import (
    NOISE_STD_Q,
    NOISE_STD_ZETA,
    OBSERVATION_SIZE,
)
from uvms_env.robot.priors import Priors, steady_inputs
from uvms_env.scenarios import Scenario, max_waypoints
from uvms_env.task.conditions import Conditions
from uvms_env.task.reward import RewardWeights
from uvms_env.task.rules import Task, TaskArrays

# Action dtype kinds accepted: float, signed and unsigned int (not bool, complex, str, object).
ACTION_KINDS = "fiu"
SEED_LIMIT = 2**63


class Engine(Protocol):
    """The physics and per-step kernels of one batch, B = () or (K,), float64 results: what
    ``EnvCore`` calls. ``uvms_env.env.scalar_engine.ScalarEngine`` and
    ``uvms_env.vector.batched_engine.BatchedEngine`` implement it (and inherit ``steady`` and
    ``features``, host calls, unless they have device kernels for them). B' is the batch
    shape of ``ids``."""

    xp: Any  # the array namespace of the step: numpy, or CuPy on a GPU
    tau_max: Any  # (8,) saturations, on the step's device
    noisy: bool  # the scenario has sensor noise

    def set_geometry(self, rows: list[int], scenarios: list[Scenario]) -> None:
        """Kernel inputs (and simulators) of new geometries for host ``rows``."""

    def reset(
        self, rows: list[int], sim_seeds: list[int], conditions: list[Conditions] | None = None
    ) -> None:
        """Start state, truth-model and current draws of ``rows`` from ``sim_seeds``, under
        each one's episode ``conditions`` (None: the scenarios')."""

    def step(self, tau: Any) -> Any:
        """One period of inputs ``tau`` B + (N, 8) in physical units; the refused steps,
        B bool (a refused environment keeps its state)."""

    def diverged_reasons(self, rows: list[int]) -> list[str]:
        """Why the last step of each of ``rows`` was refused."""

    def measure(self, ids: Any, q_noise: Any, zeta_noise: Any) -> None:
        """The sensors of ``ids`` read the true state plus this noise, B' + (N, 10) each."""

    def run_kinematics(
        self, ids: Any, action: Any, elapsed: Any, robots: Any, team: Any, measured: bool = True
    ) -> tuple:
        """The kinematics kernel on the actions B' + (N, 8) (None: zeros), the fraction of
        the time limit ``elapsed`` B', the robots' sequencers ``robots`` B' + (N, 2), the
        team's ``team`` B' + (5,) (``TEAM_INPUT``)
        and the sensors' readings (``measured=False``: the true state): observations
        B' + (N, 79) (waypoint and navigation twist after sequencing), team rows (T,) + B'
        (the team's sequencer after this call among them), constraint values
        B' + (N, 8), costs B' + (N,) and the robots' sequencers after this call
        B' + (N, 2)."""

    def wrench_sq(self, sampled: Any) -> Any:
        """B: the internal wrench's squared norm after the step where ``sampled``, from the
        step's kinematics call (its kernel samples the wrench wherever it is switched on)."""

    def object_pose(self, ids: Any) -> Any:
        """B' + (6,): the object's true pose."""

    def robots(self) -> tuple[Any, Any]:
        """B + (N, 10) each: the robots' true q and zeta."""

    def flat_state(self) -> Any:
        """B + (20 N + 12,): the true flat state (``Simulator.flat_state``)."""

    def steady(self, raw: Any, ring: float) -> Any:
        """a_ss of raw observations (..., 79) -> (..., 8) float64."""
        return steady_inputs(raw, ring)

    def features(
        self, raw: Any, steady: Any, priors: Priors, ring: float, memory: Any = None
    ) -> Any:
        """The features observation of raw observations whose a_ss is ``steady`` (and
        whose robots' memory blocks are ``memory``, in the memory mode)."""
        return priors.observe(raw, ring, steady, memory)


class EnvCore(NamespacePickled):
    """The task driven over one environment (``num_envs=None``) or K (module docstring).

    ``first_seeds``: each environment's seed before any seeded reset (None: entropy)."""

    def __init__(
        self,
        setup: EnvSetup,
        engine: Engine,
        num_envs: int | None,
        first_seeds: Sequence[int | None],
    ) -> None:
        self.setup = setup
        self.engine = engine
        self.xp = xp = engine.xp
        self.num_envs = num_envs
        self.batched = num_envs is not None
        self.k = k = num_envs or 1
        self.all: Any = slice(0, k) if self.batched else ...
        self.n = n = setup.n_agents
        self.priors = setup.priors
        self.ring = setup.scenario.object_key  # one object per core
        self.max_cycles = setup.max_cycles()
        s = setup.scenario
        self.task = Task(
            xp,
            num_envs,
            n,
            max_waypoints(setup.family, s),
            weights=setup.reward_weights,
            constraint_mode=setup.constraint_mode,
            max_cycles=self.max_cycles,
            period=s.period,
            success_pos_tol=s.success_pos_tol,
            success_att_tol=s.success_att_tol,
            internal_wrench_every=setup.internal_wrench_every,
            **setup.extensions,
        )
        self.seeders = [np.random.default_rng(seed) for seed in first_seeds]
        self.noise_rngs = [np.random.default_rng(0) for _ in range(k)]
        batch = (k,) if self.batched else ()
        self.obs = xp.zeros((*batch, n, OBSERVATION_SIZE), np.float32)  # the raw views
        self.steady = xp.zeros((*batch, n, NU)) if self.priors.needs_steady else None
        # the a_ss the command is built around: the observation's own, or in the setpoint
        # mode the holding one (``Priors.steady_source``)
        setpoint = self.priors.action_mode == "setpoint"
        self.command_steady = xp.zeros((*batch, n, NU)) if setpoint else self.steady
        # observation_mode="memory": each robot's memory of its own measurements
        self.memory = (
            Memory((*batch, n), s.period, self.ring, xp) if self.priors.remembers else None
        )
        # on the device: CuPy takes no numpy operand in its arithmetic
        self._noise_q = xp.asarray(s.sensor_noise * NOISE_STD_Q)
        self._noise_zeta = xp.asarray(s.sensor_noise * NOISE_STD_ZETA)
        self.scenarios: list[Scenario] = [s] * k
        # each environment's current episode conditions (uvms_env.task.conditions)
        self.conditions = [Conditions(s.current, s.mismatch)] * k
        self._geometry_set = np.zeros(k, bool)
        # ``command_filter(raw_obs, commands, first)`` -> commands: replaces each step's
        # normalized inputs before they reach the simulator (a safety filter in the
        # training loop); raw_obs B + (N, 79) are the observations the actions answer,
        # commands B + (N, 8) float64 what the action mode made of them, first B bool
        # marks the environments whose episode starts with this step. None: no filter.
        self.command_filter: Any = None
        self.set_geometry(list(range(k)), [s] * k)
        self.g: Any = None  # the last step's constraint values and costs (the kernel's)
        self.cost: Any = None
        # the acoustic channel (None: the silent team); its own generators, not the env's
        self.comm = setup.comm
        self.channel: Channel | None = None
        self.action_size = NU
        if self.comm is not None:
            self.channel = Channel(self.comm, xp, k, n, s.period, first_seeds)
            self.action_size = self.comm.action_size

    # -- indices ------------------------------------------------------------------------
    def ids_of(self, rows: list[int]) -> Any:
        """The array index of host ``rows``."""
        if not self.batched:
            return ...
        if len(rows) == self.k:
            return self.all  # every environment: the kernels' full path, no gathering
        return rows if self.xp is np else self.xp.asarray(rows)

    # -- geometry, seeds and resets -------------------------------------------------------
    def set_geometry(self, rows: list[int], scenarios: Sequence[Scenario]) -> None:
        """Environments ``rows`` take these scenarios' geometries (the task's waypoints,
        the engine's kernel inputs); unchanged ones are skipped."""
        changed = [
            (i, s)
            for i, s in zip(rows, scenarios, strict=True)
            if not (self.scenarios[i] is s and self._geometry_set[i])
        ]
        if not changed:
            return
        m, n, w_max = len(changed), self.n, self.task.waypoints.shape[-2]
        waypoints = np.zeros((m, w_max, 6))
        count = np.zeros(m, np.int64)
        for row, (i, s) in enumerate(changed):
            if s.n_agents != n:
                raise ValueError(f"environment {i}: {s.n_agents} agents, the batch has {n}")
            w = len(s.waypoints)
            if w > w_max:
                raise ValueError(f"environment {i}: {w} waypoints, the batch has room for {w_max}")
            waypoints[row, :w] = s.waypoints
            count[row] = w
            self.scenarios[i] = s
            self._geometry_set[i] = True
        ids = [i for i, _ in changed]
        if not self.batched:
            waypoints, count = waypoints[0], count[0]
        self.task.set_geometry(self.ids_of(ids), waypoints, count)
        self.engine.set_geometry(ids, [s for _, s in changed])

    def seed(self, rows: list[int], seeds: Sequence[int]) -> None:
        """Environments ``rows`` restart their generators from ``seeds``; a seeded family
        also takes geometry ``seed`` (``EnvSetup.geometry``)."""
        for i, s in zip(rows, seeds, strict=True):
            self.seeders[i] = np.random.default_rng(s)
        if self.channel is not None:
            self.channel.seed(rows, seeds)
        if self.setup.seeded:
            self.set_geometry(rows, [self.setup.geometry(int(s)) for s in seeds])

    def reset(self, rows: list[int]) -> None:
        """New episodes in ``rows``: the next draws of each one's generator (truth model,
        current, sensor noise; with ``randomize``, the conditions), the start state, the
        task's bookkeeping and the first observations (in ``obs``)."""
        sim_seeds = []
        for i in rows:
            rng = np.random.default_rng(self.seeders[i].integers(SEED_LIMIT))
            sim_seeds.append(int(rng.integers(SEED_LIMIT)))
            self.noise_rngs[i] = rng
        draws = self.setup.draws
        if draws is None:
            self.engine.reset(rows, sim_seeds)
        else:
            drawn = []
            for i, seed in zip(rows, sim_seeds, strict=True):
                s = self.scenarios[i]
                drawn.append(draws.draw(seed, Conditions(s.current, s.mismatch)))
                self.conditions[i] = drawn[-1]
            self.engine.reset(rows, sim_seeds, drawn)
        ids = self.ids_of(rows)
        self.task.max_cycles = self.max_cycles
        self.task.reset(ids)
        team_rows = self.refresh_observations(ids, rows, None)
        if self.memory is not None:
            self.memory.reset(ids)
        self.task.start(ids, team_rows)
        if self.channel is not None:
            self.channel.reset(ids, rows)

    # -- one step -------------------------------------------------------------------------
    def check_actions(self, actions: Any, where: str = "") -> Any:
        """B + (N, A) float64 actions of the step's namespace (A = 8, or the channel's
        ``action_size``); ValueError naming the environment and agent otherwise (``where``:
        how the caller names the array)."""
        xp, shape = self.xp, ((self.k,) if self.batched else ()) + (self.n, self.action_size)
        if actions.shape != shape:
            hint = ""
            if self.batched and actions.ndim == 3 and actions.shape[0] != self.k:
                hint = f" (num_envs is {self.k})"
            if self.comm is not None and actions.shape[-1:] != shape[-1:]:
                hint += self.comm_hint()
            raise ValueError(
                f"{where or 'actions'} must have shape {shape}, got {actions.shape}{hint}"
            )
        if actions.dtype.kind not in ACTION_KINDS:
            raise ValueError(
                f"{where or 'actions'} must be float or int (not bool, complex, str or object), "
                f"got {actions.dtype}"
            )
        a = actions.astype(np.float64, copy=False)
        if not bool(xp.isfinite(a.sum())):
            bad = self.host(xp.argwhere(~xp.isfinite(a))[0]).tolist()
            agent = f"uvms_{bad[-2]}"
            env = f"environment {bad[0]}, " if self.batched else ""
            part = "message" if bad[-1] >= NU else "action"
            raise ValueError(f"{part} of {env}agent {agent!r} contains NaN or inf")
        return a

    def comm_hint(self) -> str:
        """What an action is with the channel on (for the errors of both adapters)."""
        c = self.comm
        assert c is not None
        return (
            f" (the acoustic channel is on: {NU} inputs, a send flag (> 0: send) and "
            f"message_dim = {c.message_dim} message numbers, {c.action_size} in all; "
            "uvms_env.robot.channel.silent pads 8-number actions with silence)"
        )

    def step(self, a: Any) -> tuple[Any, Any]:
        """One period of every environment on checked actions ``a`` B + (N, 8): returns
        the task's ``StepOutcome`` and the refused steps (B bool)."""
        task, engine = self.task, self.engine
        if self.channel is not None:  # the message part goes on the air, the inputs on
            self._transmit(a)
            a = self.xp.ascontiguousarray(a[..., :NU])  # the kernels read it as one block
        command = self.priors.command(self.obs, a, self.ring, self.command_steady)
        if self.command_filter is not None:
            command = self._filtered(command)
        diverged = engine.step(command * engine.tau_max)
        task.max_cycles = self.max_cycles  # an attribute a user may change
        sampled = task.tick(diverged)
        rows = list(range(self.k)) if engine.noisy else []
        previous = self.obs.copy() if self.memory is not None else None
        # the inputs measured (the input constraint, the effort term and metric, the extra
        # terms' action) are the ones applied: the priors' and the filter's command
        team_rows = self.refresh_observations(self.all, rows, command)
        if self.memory is not None:
            self.memory.update(self.all, previous, self.obs, command)
        wrench_sq = None
        if sampled is not None and task._any(sampled):
            wrench_sq = engine.wrench_sq(sampled)
        state = None
        if task.extended:
            state = self.task_arrays(engine.object_pose(self.all), command)
        out = task.step(team_rows, self.g, self.cost, diverged, sampled, wrench_sq, state)
        return out, diverged

    def _filtered(self, command: Any) -> Any:
        """The command filter's commands, checked as an action is (they bypass the
        adapter's check): the simulator takes them as they are."""
        out = self.command_filter(self.obs, command, self.task.steps == 0)
        shape = command.shape
        wrong = getattr(out, "shape", None) != shape
        if wrong or not bool(self.xp.isfinite(out).all()):
            got = f"shape {getattr(out, 'shape', type(out).__name__)}" if wrong else "NaN or inf"
            raise ValueError(
                f"the command filter must return finite commands of shape {shape}; got {got}"
            )
        return out.astype(np.float64, copy=False)

    def _transmit(self, a: Any) -> None:
        """The channel's period: the messages of actions ``a``, sent from where the
        vehicles are at the start of the step."""
        assert self.channel is not None
        t, pos, part = self.task.steps, self.engine.robots()[0][..., :3], a[..., NU:]
        if not self.batched:  # the channel's arrays have the environment index first
            t, pos, part = t.reshape(1), pos[None], part[None]
        self.channel.step(t, part, pos)

    def refresh_observations(self, ids: Any, rows: list[int], action: Any) -> Any:
        """Measure, run the kinematics kernel (it sequences each robot's waypoints on its
        own estimate), note the state metrics: the raw observations of ``ids`` land in
        ``obs`` (their a_ss in ``steady``); returns the kernel's team rows."""
        task, engine = self.task, self.engine
        if engine.noisy:
            self._measure(ids, rows)
        seq = task.sequencing
        obs, team_rows, g, cost, seq.robots[ids] = engine.run_kinematics(
            ids, action, task.time_fraction(ids), seq.robots[ids], seq.team[ids]
        )
        self.g, self.cost = g, cost
        task.observe(ids, team_rows)
        self.obs[ids] = obs
        if self.steady is not None:  # from the float32 observations the robots see
            self.steady[ids] = engine.steady(self.obs[ids], self.ring)
            if self.command_steady is not self.steady:  # the set-point loop's holding a_ss
                source = self.priors.steady_source(self.obs[ids])
                self.command_steady[ids] = engine.steady(source, self.ring)
        return team_rows

    def _measure(self, ids: Any, rows: list[int]) -> None:
        """Sensor noise from each environment's own generator."""
        draws = [self.noise_rngs[i].standard_normal((2, self.n, NQ)) for i in rows]
        noise = self.xp.asarray(np.stack(draws) if self.batched else draws[0])
        q, zeta = noise[..., 0, :, :], noise[..., 1, :, :]
        self.engine.measure(ids, q * self._noise_q, zeta * self._noise_zeta)

    def task_arrays(self, x_o: Any, action: Any) -> TaskArrays:
        """What the extra reward terms and constraints see (K = 1 for one environment)."""
        q, zeta = self.engine.robots()
        t = self.task
        if self.batched:
            return TaskArrays(x_o, q, zeta, action, t.team_waypoint, t.goal, t.steps)
        return TaskArrays(
            x_o[None], q[None], zeta[None], action[None], t.team_waypoint[None],
            t.goal[None], t.steps.reshape(1),
        )  # fmt: skip

    # -- views ------------------------------------------------------------------------------
    def view(self, ids: Any) -> Any:
        """A copy of the observations of ``ids`` in the observation mode."""
        raw = self.obs[ids]
        if self.priors.observation_mode == "raw":
            out = raw.copy()
        else:
            memory = self.memory.block(ids) if self.memory is not None else None
            out = self.engine.features(raw, self.steady[ids], self.priors, self.ring, memory)
        if self.channel is None:
            return out
        inbox = self.channel.block(ids)
        return self.xp.concatenate([out, inbox if self.batched else inbox[0]], axis=-1)

    def state(self) -> Any:
        """B + (20 N + 19,) float32: the true state, the team's waypoint, the time fraction."""
        xp, task = self.xp, self.task
        parts = [self.engine.flat_state(), task.team_waypoint, task.time_fraction()[..., None]]
        return xp.concatenate(parts, axis=-1).astype(np.float32)

    def constraint_values(self) -> Any:
        """B + (N, C): the constraint values of the current true state with zero actions
        (no measurement, no sequencing, the episode does not advance)."""
        engine, task = self.engine, self.task
        seq = task.sequencing
        g = engine.run_kinematics(
            self.all, None, task.time_fraction(), seq.robots, seq.team, measured=False
        )[2]
        if task.constraint_fns:
            zero = self.xp.zeros((*g.shape[:-1], NU))
            extra = task.extra_constraint_values(
                self.task_arrays(engine.object_pose(self.all), zero)
            )
            g = self.xp.concatenate([g, extra], axis=-1)
        return g

    # -- ended episodes ---------------------------------------------------------------------
    def ended(self, rows: list[int], out: Any, diverged: Any) -> tuple[list, list, list]:
        """How the episodes of ``rows`` ended, their metrics and why their step was refused
        (lists over ``rows``)."""
        ids = self.ids_of(rows)
        task = self.task
        kinds = task.end_kinds(ids, out, diverged)
        metrics = task.results(ids, self.engine.object_pose(ids), out.success[ids])
        refused = self.host(diverged[ids]).reshape(-1)
        reasons = self.engine.diverged_reasons(rows) if refused.any() else [""] * len(rows)
        return kinds, metrics, [r if f else "" for r, f in zip(reasons, refused, strict=True)]


class CoreViews:
    """What ``parallel_env`` and ``VectorEnv`` expose of their ``EnvCore`` (``_core``)."""

    _core: EnvCore

    @property
    def task(self) -> Task:
        """The task's rules and the episode bookkeeping (B = () or (K,))."""
        return self._core.task

    @property
    def priors(self) -> Priors:
        return self._core.priors

    @property
    def constraint_mode(self) -> str:
        return self._core.setup.constraint_mode

    @property
    def reward_weights(self) -> RewardWeights:
        return self._core.setup.reward_weights

    @property
    def reseed_geometry(self) -> bool:
        return self._core.setup.options.get("reseed_geometry", True)

    @property
    def internal_wrench_every(self) -> int:
        return self._core.setup.internal_wrench_every

    @property
    def max_cycles(self) -> int:
        """Truncation; a user may change it between steps."""
        return self._core.max_cycles

    @max_cycles.setter
    def max_cycles(self, value: int) -> None:
        self._core.max_cycles = int(value)

    @property
    def command_filter(self) -> Any:
        """``command_filter(raw_obs, commands, first)`` -> commands, or None (``EnvCore``)."""
        return self._core.command_filter

    @command_filter.setter
    def command_filter(self, fn: Any) -> None:
        self._core.command_filter = fn
