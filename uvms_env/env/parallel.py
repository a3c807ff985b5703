"""The PettingZoo environment (native ParallelEnv): the class docstring is its documentation.

May import: numpy, gymnasium, pettingzoo and everything in ``uvms_env`` below ``env``
(``models``, ``dynamics``, ``sim``, ``navigation``, ``scenarios``) plus the ``env``
modules it composes (kinematics, observation, constraints, task, reward, metrics, wrench,
render).
"""

from __future__ import annotations

import copy
import warnings
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from uvms_env.dynamics import NQ, NU
from uvms_env.env.kinematics import TeamKinematics
from uvms_env.env.observation import (
    FAR_OBSTACLE,
    OBSERVATION_LAYOUT,
    OBSERVATION_SIZE,
    OBSERVATION_STRUCTURE,
    Observer,
    observation_bounds,
)
from uvms_env.env.priors import (
    ACTION_MODES,
    DEFAULT_RESIDUAL_SCALE,
    OBSERVATION_MODES,
    Priors,
    steady_inputs,
)
from uvms_env.env.registration import ENV_ID
from uvms_env.env.reward import RewardWeights
from uvms_env.env.task import ALL, HARD_KINDS, Task, TaskArrays, episode_end
from uvms_env.env.wrench import InternalWrench
from uvms_env.scenarios import Scenario, make, replace
from uvms_env.scenarios.overrides import (
    SCENARIO_OVERRIDES,
    Option,
    describe_options,
    validate_options,
    validate_overrides,
)
from uvms_env.sim import Simulator
from uvms_env.sim.simulator import SimulationDiverged

CONSTRAINT_MODES = ("penalize", "terminate")
# The environment's own keyword options (the scenario overrides: SCENARIO_OVERRIDES).
ENV_OPTIONS: dict[str, Option] = {
    "constraint_mode": Option("choice", "soft-constraint violations", choices=CONSTRAINT_MODES),
    "max_cycles": Option("int", "truncation; None: the scenario's max_steps", low=1, optional=True),
    "reward_weights": Option("weights", "overrides of RewardWeights", optional=True),
    "reseed_geometry": Option("bool", "reset(seed=s) also sets a seeded family's geometry"),
    "internal_wrench_every": Option("int", "internal wrench metric period, 0: never", low=0),
    "extra_reward_terms": Option(
        "functions", "extra reward terms fn(s, xp) -> (K,) (uvms_env.env.task)", optional=True
    ),
    "extra_constraints": Option(
        "functions", "extra constraints fn(s, xp) -> g (K, N) (uvms_env.env.task)", optional=True
    ),
    "action_mode": Option(
        "choice", "torque: normalized inputs; residual: around own a_ss", choices=ACTION_MODES
    ),
    "observation_mode": Option(
        "choice",
        "raw: 79 numbers; features: heading-frame features and a_ss",
        choices=OBSERVATION_MODES,
    ),
    "residual_scale": Option(
        "float", "reach of a residual action", low=0.0, high=2.0, low_open=True
    ),
    "hold_stiffness": Option(
        "float", "residual mode: joint hold about the nominal arm pose, per rad", low=0.0, high=10.0
    ),
    "hold_damping": Option(
        "float", "residual mode: joint hold damping, per rad/s", low=0.0, high=10.0
    ),
}
RESET_SEED = Option("int", "reset's seed", low=0, optional=True)
# Action dtype kinds accepted: float, signed and unsigned int (not bool, complex, str, object).
ACTION_KINDS = "fiu"
# Seeded-family scenarios kept per geometry seed (each costs an IPOPT solve to build).
GEOMETRY_CACHE_SIZE = 32
__all__ = ["HARD_KINDS", "CoopTransportEnv", "episode_end", "parallel_env"]  # re-exported


@dataclass
class _World:
    """Everything that depends on one scenario's geometry."""

    scenario: Scenario
    sim: Simulator
    kinematics: TeamKinematics
    observer: Observer
    task: Task  # the task's rules and bookkeeping, K = 1
    wrench: InternalWrench
    renderer: Any = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "renderer": None}  # a window is no state; rebuilt on demand


class CoopTransportEnv(ParallelEnv[str, np.ndarray, np.ndarray]):
    """Cooperative transport: N underwater vehicle-manipulator systems carry one object.

    | | |
    |---|---|
    | Import | `uvms_env.parallel_env(scenario="paper", render_mode=None, **overrides)` |
    | PettingZoo | `pettingzoo.make("parallel", "uvms_env/CoopTransport-v0")` |
    | Gymnasium | `gymnasium.make("uvms_env/CoopTransport-v0")`: centralized view |
    | Agents | `uvms_0 ... uvms_{N-1}`; paper, short N = 2; random N = 2..6 (default 2) |
    | Action space | `Box(-1, 1, (8,), float32)` per agent |
    | Observation space | `Box(79,)` float32 per agent, local only (layout below) |
    | State space | `Box(20 N + 19,)` float32, the global state for centralized critics only |
    | Control period | h = `scenario.period` = 0.12 s; one `step` is one period |

    Several UVMSs (vehicle + 4-DoF arm) rigidly grasp one object and carry it past
    obstacles through a list of waypoints. Each robot decides from its own observation:
    its own measured state and what it knows before the task, nothing measured by
    another robot and no contact force (a test proves it). The truth is the closed-chain
    simulator `uvms_env.sim.Simulator`.

    **Actions.** Normalized inputs of robot i, scaled by the saturation limits
    (`load_parameters().limits.tau_max`); values beyond [-1, 1] are clipped (the
    simulator saturates) and reported by the `input` constraint. Float or integer
    arrays (or lists); bool, complex, string and object arrays, NaN and inf raise
    ValueError naming the agent.

    | index | input | unit | scale (saturation) |
    |---|---|---|---|
    | 0 | surge force X | N | 10 |
    | 1 | sway force Y | N | 10 |
    | 2 | heave force Z | N | 10 |
    | 3 | yaw moment N | N m | 10 |
    | 4-7 | joint torques tau_1 .. tau_4 | N m | 2 |

    **Observations** (per robot; names and slices in `env.observation_structure`; a test
    checks this table against it):

    | index | meaning | frame | unit |
    |---|---|---|---|
    | 0-9 | `q`: own x y z, phi theta psi, q1..q4 (measured) | NED, ZYX Euler | m, rad |
    | 10-19 | `zeta`: own u v w, p q r, qd1..qd4 (measured) | body; joints | m/s, rad/s |
    | 20-25 | `object_pose`: own estimate of p_O, Theta_O (1) | NED, ZYX Euler | m, rad |
    | 26-31 | `object_twist`: own estimate of p_dot_O, omega_O (2) | NED | m/s, rad/s |
    | 32-37 | `waypoint`: active waypoint, own sequencing (3) | NED, ZYX Euler | m, rad |
    | 38-43 | `goal`: final waypoint | NED, ZYX Euler | m, rad |
    | 44-49 | `nav_velocity`: navigation twist: v_d, Euler-angle rates (3) | NED | m/s, rad/s |
    | 50-64 | `obstacles`: 3 nearest, each dx dy dz radius is_cylinder (4) | NED | m, 1 |
    | 65 | `load_share`: c_i | - | 1 |
    | 66-68 | `grasp_offset`: l_i | object frame | m |
    | 69-77 | `grasp_rotation`: R_Oi, row-major | object frame | 1 |
    | 78 | `time_fraction`: t / (max_cycles h) | - | 1 |

    (1) From the robot's own measured q and its known grasp: p_O = p_ee - R_O l_i,
    R_O = R_ee R_Oi^T, as ZYX Euler angles. (2) [p_dot_O; omega_O] = J_Oi^-1 J_i zeta_i
    with J_Oi^-1 = [[I, S(R_O l_i)], [0, I]]. (3) Each robot's own `WaypointSequencer`
    passes a waypoint when its own estimate is within 0.3 m; `nav_velocity` is its
    `WaypointNavigator` twist (`uvms_env.env.observation.make_navigator(scenario)`) at
    its own estimate. (4) dx dy dz = obstacle centre minus the own object estimate
    (dz = 0 for the vertical cylinders, infinite in z), nearest first by surface
    distance, padded with [100, 100, 0, 0, 0].

    **Sensor noise** (scenario `sensor_noise` = s > 0): Gaussian on q and zeta before
    any estimate is derived, std per component times s: position 0.02 m, Euler angles
    0.01 rad, joint angles 0.01 rad; linear velocity 0.01 m/s, angular velocity and
    joint rates 0.005 rad/s. Drawn from the episode's seeded generator.

    **State** (`state()`, `env.state_structure`): the true `q` (10 N), `zeta` (10 N),
    object pose (6) and twist (6), the team's active waypoint (6) and the time fraction.

    **Reward** (shared: computed once per step, the same for every agent; every term in
    `infos[agent]["reward_terms"]`, and the reward is their sum):

        r = progress + waypoint + success + violation + effort
        progress  = 10 (Phi_prev - Phi),  Phi = |p_O - p_wp| + 0.5 |wrap(Theta_O - Theta_wp)|
        waypoint  = 5 when the true object passes an intermediate waypoint
        success   = 50 when the episode succeeds
        violation = -0.5 (violated constraints summed over robots) / N - 50 [failure]
        effort    = -0.05 mean(a^2)

    on the true object and the team's waypoint (details and weights:
    `uvms_env.env.reward`; change them with `reward_weights`).

    **Constraints** (`infos[agent]["constraint_values"]`, g <= 0 holds; the true state):
    input, joint_limit, joint_speed, vehicle_speed, manipulability (eps = 0.5; ~4.2 at
    the paper's start), representation, collision, workspace; definitions in
    `uvms_env.env.constraints`. `infos[agent]["cost"]` is the number of the robot's
    violated constraints. Collisions always end the episode; the others end it in
    `constraint_mode="terminate"` and only cost reward in `"penalize"` (default).

    **Starting state.** The scenario's start, at rest: a static equilibrium that holds
    the grasps exactly, kept by the normalized actions `env.sim.holding_inputs() /
    env.sim.tau_max` (not by zero actions).

    **Episode end.** Terminated: success (the true object within `success_pos_tol` =
    0.15 m and `success_att_tol` = 0.1 rad of the final waypoint), a collision, a
    violation in "terminate" mode, or a diverged simulation: a period the simulator's
    error control could not integrate to its accuracy even in 16 parts, or a state beyond
    the model's physical envelope (`uvms_env.sim.simulator.SPEED_LIMITS`). The step is
    refused, its observation is the last valid state's, the episode ends as a failure
    and `infos[agent]["diverged_reason"]` says why. Truncated: `max_cycles` periods. All
    agents end together. The last infos carry `"episode_end"` (success, collision, constraint,
    diverged, max_cycles) and `"metrics"` (`uvms_env.env.metrics`).

    **Infos.** Every step, per agent: `constraint_values` (dict), `cost`, `reward_terms`
    (dict); at the end also `episode_end` and `metrics` (the same dict for every agent;
    `policy_time_ms` is left None). The internal wrench metric costs ~20 us (~6% of a
    step); `internal_wrench_every=0` drops it (e.g. for training).

    **Rendering.** `render_mode="rgb_array"`: `render()` returns a 720 x 360 x 3 uint8
    top and side view (vehicles, arms, object, obstacles, waypoints, the object's path);
    "human" shows it in a window when a display exists and otherwise warns once.
    `uvms_env.env.save_video(frames, "episode.gif")` writes GIF (or MP4 with imageio).

    **Beyond the API.** `env.sim` and `env.scenario` (global: never feed them to a
    policy), `env.observe()` (observations of the current state, e.g. after
    `sim.set_state`), `env.constraint_values()`, `env.task` (the task's rules and this
    episode's bookkeeping: `uvms_env.env.task.Task` for one environment, the code
    `VectorEnv` runs over K environments).

    **Extensions** (no change to the package): `extra_reward_terms={"name": fn}` adds
    `fn(s, xp)` (K,) to the reward, reported as `reward_terms["name"]`;
    `extra_constraints={"name": fn}` adds a constraint g = `fn(s, xp)` (K, N), g <= 0
    holds, to `constraint_values`, `cost`, the violation term, `metrics["violations"]` and
    `constraint_mode="terminate"`. `fn` is a callable or a `"module:function"` string;
    `s` is a `uvms_env.env.task.TaskArrays` (true object pose, q, zeta, actions,
    waypoints, steps over K environments, here K = 1) and `xp` numpy or CuPy: the same
    function serves `VectorEnv` on both backends.

    **Arguments**

    | name | type | default | meaning |
    |---|---|---|---|
    | scenario | str or Scenario | "paper" | family ("paper", "random", "short") or a Scenario |
    | render_mode | None, "rgb_array", "human" | None | "human" is headless-safe |
    | n_agents | int | 2 | random family: 2..6; paper and short: 2 |
    | current | str | "none" | ocean current preset: none, mild, strong |
    | damping_scale | float >= 0 | 1.0 | multiplies all damping |
    | mismatch | float in [0, 0.5) | 0.0 | relative truth-model perturbation, per episode |
    | sensor_noise | float >= 0 | 0.0 | scale of the sensor noise above |
    | seed | None or int >= 0 | None | scenario seed: random geometry, default episode seed |
    | max_steps, substeps | int >= 1 | scenario's | scenario fields |
    | success_pos_tol, success_att_tol | float > 0 | scenario's | scenario fields |
    | constraint_mode | str | "penalize" | "penalize" or "terminate" |
    | max_cycles | None or int >= 1 | scenario max_steps | truncation (also an attribute) |
    | reward_weights | dict str -> float | {} | overrides of `RewardWeights` |
    | reseed_geometry | bool | True | seeded families: `reset(seed=s)` uses geometry seed s |
    | internal_wrench_every | int >= 0 | 1 | internal wrench metric every k periods (0: never) |
    | extra_reward_terms | dict str -> fn | None | extra reward terms (Extensions) |
    | extra_constraints | dict str -> fn | None | extra constraints (Extensions) |

    Every keyword is checked against one typed table (`SCENARIO_OVERRIDES` in
    `uvms_env.scenarios.overrides`, `ENV_OPTIONS` here): a wrong type raises TypeError
    (no bools or strings for numbers, no floats for integers), a value out of range
    (NaN and inf included) or an unknown keyword ValueError; the message names the
    keyword and lists what is allowed.

    **Seeding.** `seed`: None or an int >= 0 (Python or numpy, not bool; else TypeError
    or ValueError). `reset(seed=s)` reseeds everything random in an episode: the truth
    model's mismatch draws, the current and the sensor noise; `reset()` continues the
    sequence, so a seeded reset followed by the same actions replays an episode step
    for step. For the families whose geometry is seeded ("random", "short"; not
    "paper") and `reseed_geometry=True`, `reset(seed=s)` also sets the geometry to
    `make(family, seed=s, n_agents=N, ...)` (the last 32 are cached; the first build of
    a seed costs an IPOPT solve, ~0.2-1 s); `reset()` keeps the current geometry. With
    `reseed_geometry=False` the geometry stays the one built at construction (from the
    `seed` override; without one it is a fresh draw). The number of agents never
    changes and never depends on a seed: two environments built with the same
    arguments and reset with the same seed are identical.

    **Version history.** v0 (2026-11): first version.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["human", "rgb_array"],
        "name": ENV_ID,
        "is_parallelizable": True,
        "render_fps": 8,
    }

    def __init__(
        self, scenario: str | Scenario = "paper", render_mode: str | None = None, **overrides: Any
    ) -> None:
        overrides, options, _ = split_keywords(overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.constraint_mode = options.get("constraint_mode", "penalize")
        self.reward_weights = RewardWeights.from_mapping(options.get("reward_weights"))
        self.reseed_geometry = options.get("reseed_geometry", True)
        self.internal_wrench_every = options.get("internal_wrench_every", 1)
        self.priors = priors_of(options)
        self._extensions = {k: options.get(k) for k in ("extra_reward_terms", "extra_constraints")}

        if isinstance(scenario, Scenario):
            if "n_agents" in overrides:
                raise ValueError("n_agents cannot be overridden on a built Scenario")
            built = replace(scenario, **overrides) if overrides else scenario
            self._family: str | None = None
        elif isinstance(scenario, str):
            built = _make_scenario(scenario, overrides)
            self._family = scenario
        else:
            raise ValueError(f"scenario must be a family name or a Scenario, got {scenario!r}")
        self._overrides = {**overrides, "n_agents": built.n_agents}
        # Every family but the paper's draws its geometry from the seed.
        self._seeded_geometry = self.reseed_geometry and self._family not in (None, "paper")
        max_cycles = options.get("max_cycles")
        self.max_cycles = int(built.max_steps) if max_cycles is None else max_cycles

        n = built.n_agents
        self.n = n
        self.possible_agents = [f"uvms_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.observation_spaces = {a: observation_space(self.priors) for a in self.possible_agents}
        self.action_spaces = {
            a: spaces.Box(-1.0, 1.0, (NU,), np.float32) for a in self.possible_agents
        }
        self.observation_structure = dict(OBSERVATION_STRUCTURE)
        self.state_structure = _state_structure(n)
        size = self.state_structure["time_fraction"].stop
        self.state_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)

        self._worlds: OrderedDict[int, _World] = OrderedDict()
        self._world = self._build_world(built)
        if self._seeded_geometry and built.seed is not None:
            self._worlds[int(built.seed)] = self._world
        self._seeder = np.random.default_rng(built.seed)
        self._zero_action = np.zeros((n, NU))
        self._raw_obs = np.zeros((n, OBSERVATION_SIZE), np.float32)  # what the robots saw last
        self._steady: np.ndarray | None = None  # their a_ss, when the priors use it
        self._path: list[np.ndarray] = []

    # -- public views ------------------------------------------------------------------
    @property
    def scenario(self) -> Scenario:
        return self._world.scenario

    @property
    def sim(self) -> Simulator:
        """The truth simulator (global information: never feed it to a policy)."""
        return self._world.sim

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[self._agent(agent)]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[self._agent(agent)]

    @property
    def task(self) -> Task:
        """The task's rules and episode bookkeeping (one environment): metrics so far,
        sequencing."""
        return self._world.task

    def state(self) -> np.ndarray:
        w = self._world
        return np.concatenate(
            [w.sim.flat_state, w.task.team_waypoint, [w.task.time_fraction()]], dtype=np.float32
        )

    # -- episode -----------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode (``options`` is accepted and unused)."""
        if seed is not None:
            seed = RESET_SEED.check("seed", seed)
            self._seeder = np.random.default_rng(seed)
            if self._seeded_geometry:
                self._world = self._world_for_seed(int(seed))
        w = self._world
        rng = np.random.default_rng(self._seeder.integers(2**63))
        w.sim.reset(seed=int(rng.integers(2**63)))
        w.task.max_cycles = self.max_cycles
        w.task.reset(ALL)
        w.observer.reset(rng, w.task)
        self._bind(w)
        self.agents = self.possible_agents[:]
        obs = self._observe(self._zero_action)
        w.task.start(ALL, self._x_o)
        self._path = [self._x_o[:3].copy()]
        return (
            {a: obs[i] for i, a in enumerate(self.possible_agents)},
            {a: {} for a in self.possible_agents},
        )

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        w = self._world
        a = self._parse_actions(actions)
        ring = w.scenario.object_ring_radius
        command = self.priors.command(self._raw_obs, a, ring, self._steady)
        diverged = ""
        try:
            info = w.sim.step(command * w.sim.tau_max)  # it saturates: clip(a) tau_max
        except SimulationDiverged as exc:
            diverged = str(exc)  # the simulator kept the last valid state
        except ValueError as exc:  # NaN or inf: the simulator checks before it steps
            raise self._bad_actions(a) from exc
        task = w.task
        task.max_cycles = self.max_cycles  # an attribute a user may change
        refused = np.bool_(bool(diverged))
        sampled = task.tick(refused)
        obs = self._observe(a)
        kin = w.kinematics
        wrench_sq = None
        if sampled is not None and sampled:
            wrench_sq = w.wrench(info.tau_applied, info.current)
        out = task.step(
            self._x_o,
            kin.team_rows(),
            kin.constraints,
            kin.violated_count,
            refused,
            sampled,
            wrench_sq,
            self._task_arrays(a) if task.extended else None,
        )
        terminated, truncated = bool(out.terminated), bool(out.truncated)
        reward = float(out.reward)
        terms = {name: float(v) for name, v in out.terms.items()}
        if self.render_mode is not None:
            self._path.append(self._x_o[:3].copy())

        agents = self.possible_agents
        g_rows = out.constraint_values.tolist()
        costs = out.cost.tolist()
        names = task.constraints
        infos = {
            agent: {
                "constraint_values": dict(zip(names, g_rows[i], strict=True)),
                "cost": costs[i],
                "reward_terms": dict(terms),
            }
            for i, agent in enumerate(agents)
        }
        if terminated or truncated:
            end = task.end_kinds(ALL, out, refused)[0]
            if diverged:
                for info_a in infos.values():
                    info_a["diverged_reason"] = diverged
            metrics = task.results(ALL, self._x_o, out.success)[0]
            for info_a in infos.values():
                info_a["episode_end"] = end
                info_a["metrics"] = metrics
            self.agents = []
        return (
            {agent: obs[i] for i, agent in enumerate(agents)},
            dict.fromkeys(agents, reward),
            dict.fromkeys(agents, terminated),
            dict.fromkeys(agents, truncated),
            infos,
        )

    def _task_arrays(self, action: np.ndarray) -> TaskArrays:
        """What the extra reward terms and constraints see (views with K = 1)."""
        task = self._world.task
        return TaskArrays(
            self._x_o[None],
            self._q[None],
            self._zeta[None],
            action[None],
            task.team_waypoint[None],
            task.goal[None],
            task.steps.reshape(1),
        )

    def _evaluate(self, action: np.ndarray) -> np.ndarray:
        """Measure, run the kinematics kernel, note the state metrics, build the (N, 79)
        observations. ``action``: the requested normalized actions (input constraint)."""
        w = self._world
        kin = w.kinematics
        kin.time_fraction[0] = w.task.time_fraction()
        q_meas, zeta_meas = w.observer.measure(self._q, self._zeta)
        kin(action, self._q, self._zeta, q_meas, zeta_meas, self._x_o)
        team = kin.team_rows()
        w.task.observe(ALL, team)
        return w.observer.build(w.task, team)

    def _observe(self, action: np.ndarray) -> np.ndarray:
        """``_evaluate``, kept as the robots' last raw view, then the observation mode."""
        self._raw_obs = raw = self._evaluate(action)
        ring = self._world.scenario.object_ring_radius
        self._steady = steady_inputs(raw, ring) if self.priors.needs_steady else None
        return self.priors.observe(raw, ring, self._steady)

    def observe(self) -> dict[str, np.ndarray]:
        """Observations of the simulator's current state, e.g. after ``sim.set_state`` in a
        replay or a test. Measures like a step (draws sensor noise, may advance the
        robots' waypoint sequencers) but does not advance time or touch the reward."""
        self._bind(self._world)
        obs = self._observe(self._zero_action)
        return {a: obs[i] for i, a in enumerate(self.possible_agents)}

    def constraint_values(self) -> dict[str, dict[str, float]]:
        """Constraint values of the current true state (zero actions), per agent: for
        checks and tests; it does not advance the episode."""
        w = self._world
        self._bind(w)
        zero = self._zero_action
        w.kinematics(zero, self._q, self._zeta, self._q, self._zeta, self._x_o)
        g = w.kinematics.constraints
        if w.task.constraint_fns:
            extra = w.task.extra_constraint_values(self._task_arrays(zero))
            g = np.concatenate([g, extra], axis=-1)
        rows = g.tolist()
        return {
            a: dict(zip(w.task.constraints, rows[i], strict=True))
            for i, a in enumerate(self.possible_agents)
        }

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            warnings.warn(
                "render() called with render_mode=None; pass render_mode='rgb_array' or "
                "'human' to the environment",
                stacklevel=2,
            )
            return None
        w = self._world
        if w.renderer is None:
            from uvms_env.env.render import Renderer

            w.renderer = Renderer(w.scenario, w.sim.object.segments)
        st = w.sim.state
        frame = w.renderer.frame(st.q, st.x_O, np.array(self._path), st.t)
        if self.render_mode == "rgb_array":
            return frame
        w.renderer.show(frame)
        return None

    def close(self) -> None:
        for world in (self._world, *self._worlds.values()):
            if world.renderer is not None:
                world.renderer.close()

    # -- copies ------------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """Pickles (and deep copies) hold the current world and the episode's state; the
        copy rebuilds its compiled functions from the disk cache and continues the same
        episode bit for bit. Cached worlds of other geometry seeds are left out (each
        would rebuild its compiled functions)."""
        state = dict(self.__dict__)
        state["_worlds"] = OrderedDict(
            (seed, w) for seed, w in self._worlds.items() if w is self._world
        )
        for view in ("_q", "_zeta", "_x_o"):  # views into the simulator's state
            state.pop(view, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind(self._world)

    def __copy__(self) -> CoopTransportEnv:
        """An independent copy: a shallow one would share the simulator."""
        return copy.deepcopy(self)

    # -- internals ---------------------------------------------------------------------
    def _agent(self, agent: str) -> str:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents: {self.possible_agents}")
        return agent

    def _parse_actions(self, actions: Mapping[str, Any]) -> np.ndarray:
        """(N, 8) float64 requested actions; ValueError naming the agent otherwise."""
        if type(actions) is not dict and not isinstance(actions, Mapping):  # dict: fast
            raise ValueError(
                f"actions must be a dict agent -> array of shape ({NU},), got {type(actions)}"
            )
        try:  # fast path: real (float or int) rows of shape (8,), one conversion for all
            rows = [np.asarray(actions[agent]) for agent in self.possible_agents]
        except (KeyError, ValueError, TypeError):
            rows = None
        if rows is None or not all(
            [r.dtype.kind in ACTION_KINDS and r.shape == (NU,) for r in rows]
        ):
            self._explain_bad_actions(actions)
        a = np.array(rows, dtype=float)
        if len(actions) != self.n:
            unknown = sorted(set(actions) - set(self._index), key=str)
            raise ValueError(
                f"actions for unknown agent(s) {unknown}; agents: {self.possible_agents}"
            )
        return a  # finiteness: the simulator checks it (see step)

    def _bad_actions(self, a: np.ndarray) -> ValueError:
        bad = np.argwhere(~np.isfinite(a))
        if not len(bad):
            return ValueError("the simulator rejected the actions")
        return ValueError(
            f"action of agent {self.possible_agents[bad[0, 0]]!r} contains NaN or inf"
        )

    def _explain_bad_actions(self, actions: Mapping[str, Any]) -> None:
        for agent in self.possible_agents:
            if agent not in actions:
                raise ValueError(f"no action for agent {agent!r}: every live agent must act")
            act = actions[agent]
            try:
                arr = np.asarray(act)
            except (TypeError, ValueError) as exc:  # e.g. ragged nested lists
                raise ValueError(f"action of agent {agent!r} is not an array: {act!r}") from exc
            if arr.dtype.kind not in ACTION_KINDS:
                raise ValueError(
                    f"action of agent {agent!r} is not numeric: dtype {arr.dtype} (allowed: "
                    f"float or int; not bool, complex, str or object), got {act!r}"
                )
            if arr.shape != (NU,):
                raise ValueError(
                    f"action of agent {agent!r} must have shape ({NU},), got {arr.shape}"
                )
        raise ValueError("actions could not be read")  # not reached: some agent is wrong

    def _bind(self, w: _World) -> None:
        """Views into the simulator's state (kept across steps: it is updated in place)."""
        x, n = w.sim.flat_state, self.n
        self._q = x[: NQ * n].reshape(n, NQ)
        self._zeta = x[NQ * n : 2 * NQ * n].reshape(n, NQ)
        self._x_o = x[2 * NQ * n : 2 * NQ * n + 6]

    def _build_world(self, scenario: Scenario) -> _World:
        sim = Simulator(scenario)
        kin = TeamKinematics(scenario, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE)
        return _World(
            scenario=scenario,
            sim=sim,
            kinematics=kin,
            observer=Observer(scenario, kin),
            task=task_of(scenario, self, None, len(scenario.waypoints), np),
            wrench=InternalWrench(sim),
        )

    def _world_for_seed(self, seed: int) -> _World:
        """The world of geometry seed ``seed`` (built once, then cached)."""
        if seed in self._worlds:
            self._worlds.move_to_end(seed)
            return self._worlds[seed]
        assert self._family is not None
        scenario = _make_scenario(self._family, {**self._overrides, "seed": seed})
        world = self._build_world(scenario)
        self._worlds[seed] = world
        while len(self._worlds) > GEOMETRY_CACHE_SIZE:
            old = self._worlds.popitem(last=False)[1]
            if old.renderer is not None and old is not self._world:
                old.renderer.close()
        return world


def task_of(scenario: Scenario, env: Any, num_envs: int | None, w_max: int, xp: Any) -> Task:
    """The ``Task`` of ``num_envs`` environments (None: one, without a batch axis) with
    ``env``'s options (the single env's or the vector env's attributes), all on
    ``scenario``'s geometry to start with."""
    task = Task(
        xp,
        num_envs,
        scenario.n_agents,
        w_max,
        weights=env.reward_weights,
        constraint_mode=env.constraint_mode,
        max_cycles=env.max_cycles,
        period=scenario.period,
        success_pos_tol=scenario.success_pos_tol,
        success_att_tol=scenario.success_att_tol,
        internal_wrench_every=env.internal_wrench_every,
        **env._extensions,
    )
    b, w = task.batch, len(scenario.waypoints)
    waypoints = np.zeros((*b, w_max, 6))
    waypoints[..., :w, :] = scenario.waypoints
    task.set_geometry(ALL, waypoints, np.full(b, w), np.full(b, bool(scenario.obstacles)))
    return task


def priors_of(options: Mapping[str, Any]) -> Priors:
    """The action and observation modes among checked environment ``options``."""
    return Priors(
        options.get("action_mode", "torque"),
        options.get("observation_mode", "raw"),
        options.get("residual_scale", DEFAULT_RESIDUAL_SCALE),
        options.get("hold_stiffness", 0.0),
        options.get("hold_damping", 0.0),
    )


def observation_space(priors: Priors) -> spaces.Box:
    """One robot's observation space: the raw layout's bounds, or unbounded features."""
    if priors.observation_mode == "raw":
        low, high = observation_bounds()
        return spaces.Box(low, high, (OBSERVATION_SIZE,), np.float32)
    return spaces.Box(-np.inf, np.inf, (priors.observation_size,), np.float32)


def split_keywords(
    keywords: Mapping[str, Any], extra: Mapping[str, Option] | None = None, extra_name: str = ""
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """``keywords`` split into (scenario overrides, environment options, ``extra`` options),
    each checked against its table (``extra``: a caller's own, e.g. the vector env's); an
    unknown keyword raises ValueError listing every allowed one."""
    extra = extra or {}
    unknown = sorted(
        set(keywords) - set(SCENARIO_OVERRIDES) - set(ENV_OPTIONS) - set(extra), key=str
    )
    if unknown:
        more = f"; {extra_name} options {describe_options(extra)}" if extra else ""
        raise ValueError(
            f"unknown option(s) {unknown}; allowed: scenario overrides "
            f"{describe_options(SCENARIO_OVERRIDES)}; environment options "
            f"{describe_options(ENV_OPTIONS)}{more}"
        )
    rest = dict(keywords)
    options = {k: rest.pop(k) for k in ENV_OPTIONS if k in rest}
    own = {k: rest.pop(k) for k in extra if k in rest}
    return (
        validate_overrides(rest),
        validate_options(options, ENV_OPTIONS, "environment option"),
        validate_options(own, extra, f"{extra_name} option") if extra else {},
    )


def _make_scenario(name: str, overrides: dict[str, Any]) -> Scenario:
    """``make(name, **overrides)``, shared between environments when it is deterministic
    (scenarios are immutable; building one costs an IPOPT solve)."""
    if name != "paper" and overrides.get("seed") is None:  # a fresh random geometry
        return make(name, **overrides)
    try:
        return _make_cached(name, tuple(sorted(overrides.items())))
    except TypeError:  # an unhashable override value: build it, make() validates it
        return make(name, **overrides)


@lru_cache(maxsize=GEOMETRY_CACHE_SIZE)
def _make_cached(name: str, overrides: tuple[tuple[str, Any], ...]) -> Scenario:
    return make(name, **dict(overrides))


def _state_structure(n: int) -> dict[str, slice]:
    sizes = {
        "q": NQ * n,
        "zeta": NQ * n,
        "object_pose": 6,
        "object_twist": 6,
        "waypoint": 6,
        "time_fraction": 1,
    }
    out, start = {}, 0
    for name, size in sizes.items():
        out[name] = slice(start, start + size)
        start += size
    return out


def parallel_env(
    scenario: str | Scenario = "paper", render_mode: str | None = None, **overrides: Any
) -> CoopTransportEnv:
    """The cooperative transport environment (see ``CoopTransportEnv``)."""
    return CoopTransportEnv(scenario, render_mode, **overrides)
