"""The PettingZoo environment (native ParallelEnv): the class docstring is its documentation.

A dict adapter: the episode's flow is ``uvms_env.env.core.EnvCore`` for one environment on
the scalar engine (``uvms_env.env.scalar_engine``), the code ``VectorEnv`` runs for K; here are
the PettingZoo API, the agents' names and rendering.

May import: numpy, gymnasium, pettingzoo and everything in ``uvms_env`` below ``env``
(``models``, ``dynamics``, ``sim``, ``navigation``, ``scenarios``) plus the ``env``
modules it composes (core, engine, options, observation, task, render).
"""

from __future__ import annotations

import copy
import warnings
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from uvms_env.env.core import ACTION_KINDS, CoreViews, EnvCore
from uvms_env.env.infos import InfoLayout
from uvms_env.env.options import (
    RESET_SEED,
    action_space,
    observation_space,
    observation_structure,
    resolve,
    state_structure,
)
from uvms_env.env.registration import ENV_ID
from uvms_env.env.scalar_engine import ScalarEngine
from uvms_env.scenarios import Scenario
from uvms_env.sim import Simulator
from uvms_env.task.rules import HARD_KINDS, episode_end

__all__ = ["HARD_KINDS", "CoopTransportEnv", "episode_end", "parallel_env"]  # re-exported


class CoopTransportEnv(ParallelEnv[str, np.ndarray, np.ndarray], CoreViews):
    """Cooperative transport: N underwater vehicle-manipulator systems carry one object.

    | | |
    |---|---|
    | Import | `uvms_env.parallel_env(scenario="paper", render_mode=None, **overrides)` |
    | PettingZoo | `pettingzoo.make("parallel", "uvms_env/CoopTransport-v1")` |
    | Gymnasium | `gymnasium.make("uvms_env/CoopTransport-v1")`: centralized view |
    | Agents | `uvms_0 ... uvms_{N-1}`; paper, short N = 2; random N = 2..8 (default 2) |
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

    Notes (1)-(4): docs/options.md, "Observations".

    **Sensor noise** (scenario `sensor_noise` = s > 0): Gaussian on q and zeta before
    any estimate is derived, std per component times s: position 0.02 m, Euler angles
    0.01 rad, joint angles 0.01 rad; linear velocity 0.01 m/s, angular velocity and
    joint rates 0.005 rad/s. Drawn from the episode's seeded generator.

    **State** (`state()`, `env.state_structure`): the true `q` (10 N), `zeta` (10 N),
    object pose (6) and twist (6), the team's active waypoint (6) and the time fraction.

    **Reward** (shared: computed once per step, the same for every agent; every term in
    `infos[agent]["reward_terms"]`, and the reward is their sum): the formulas and
    weights are `uvms_env.task.reward`'s; change them with `reward_weights`.

    **Constraints** (`infos[agent]["constraint_<kind>"]`, g <= 0 holds, on the true state;
    the kinds and their definitions: `uvms_env.task.constraints`). `infos[agent]["cost"]`
    is the number of the robot's violated safety constraints (every kind but `input`, which
    is reported but clipped before the simulator). Collisions always end the episode; the
    others end it in `constraint_mode="terminate"` and only cost reward in `"penalize"`
    (default).

    **Starting state.** The scenario's start, at rest: a static equilibrium that holds
    the grasps exactly, kept by the normalized actions `env.sim.holding_inputs() /
    env.sim.tau_max` (not by zero actions).

    **Episode end.** Terminated: success (the true object within `success_pos_tol` =
    0.15 m and `success_att_tol` = 0.1 rad of the final waypoint), a collision, a
    violation in "terminate" mode, or a diverged simulation: a period the simulator's
    error control could not integrate to its accuracy even in 16 parts, or a state beyond
    the model's physical envelope (`uvms_env.sim.simulator.SPEED_LIMITS`). The step is
    refused, its observation is the last valid state's, the episode ends as a failure,
    `infos[agent]["diverged"]` is 1 and `env.diverged_reason` says why. Truncated:
    `max_cycles` periods. All agents end together. The last infos carry the code of how
    the episode ended, `"episode_end"` (`uvms_env.env.infos.EPISODE_END_NAMES`: 1 success,
    2 diverged, 3 collision, 4 constraint, 5 max_cycles; 0 while it runs), and the
    episode's metrics (`uvms_env.task.metrics`: success, clean success, the graded safety
    per kind, the return, ...).

    **Infos** (`uvms_env.env.infos`): per agent one flat dict of numbers with the same
    keys (`env.info_keys`) at `reset` and at every step, so that TorchRL's
    `PettingZooWrapper(env=parallel_env(...))` carries them: `cost`,
    `constraint_<kind>`, `reward_<term>`, `episode_end`, `diverged`, and the metrics
    (zeros until the step that ends the episode; the same values for every agent).
    `uvms_env.env.infos.episode_metrics(info)` reads them back. The internal wrench
    metric costs ~20 us (~6% of a step); `internal_wrench_every=0` drops it (e.g. for
    training).

    **Rendering.** `render_mode="rgb_array"`: `render()` returns a (360, 720, 3) uint8
    array (height, width, RGB), a top and a side view (`uvms_env.env.render`); "human"
    and videos: docs/environment.md.

    **Beyond the API.** `env.sim` and `env.scenario` (global: never feed them to a
    policy), `env.observe()` (observations of the current state, e.g. after
    `sim.set_state`), `env.constraint_values()`, `env.task` (the task's rules and this
    episode's bookkeeping: `uvms_env.task.rules.Task` for one environment, the code
    `VectorEnv` runs over K environments), `env.command_filter` (a function that replaces
    each step's normalized inputs before the simulator, e.g. a safety filter:
    `uvms_env.env.core.EnvCore`).

    **Extensions** (no change to the package): `extra_reward_terms={"name": fn}` and
    `extra_constraints={"name": fn}`, `fn(s, xp)` with `s` a
    `uvms_env.task.rules.TaskArrays` (here K = 1): docs/environment.md, "Extension points".

    **Communication** (`comm=`; default None: the silent team, nothing changes). With an
    acoustic channel (`uvms_env.robot.channel`: a preset `ideal`, `micromodem_fsk`, `atm900`,
    `s2c_48_78`, a `ChannelSettings` or `{"preset": name, field: value}`) each action is
    `Box(-1, 1, (8 + 1 + D,))` (inputs, send flag, message) and each observation gains the
    inbox `messages`; an 8-number action raises ValueError. The layouts and the channel's
    model: docs/channel.md.

    **Arguments**: `scenario` (a family, "paper", "random" or "short", or a `Scenario`),
    `render_mode` and the keywords tabled with their types, defaults and meanings in
    docs/options.md, "Environment options" (a test keeps that table and the code in step):
    the scenario overrides (`uvms_env.scenarios.overrides.SCENARIO_OVERRIDES`) and
    `uvms_env.env.options.ENV_OPTIONS`. A wrong type raises TypeError (no bools or strings
    for numbers, no floats for integers), a value out of range (NaN and inf included) or an
    unknown keyword ValueError; the message names the keyword and lists what is allowed.

    **Seeding** (docs/environment.md, "Seeding"). `seed`: None or an int >= 0 (Python or
    numpy, not bool; else TypeError or ValueError); `reset()` continues the sequence and
    keeps the current geometry. With `reseed_geometry=False` the geometry stays the one
    built at construction (from the `seed` override; without one it is a fresh draw).
    The number of agents never changes and never depends on a seed: two environments
    built with the same arguments and reset with the same seed are identical.

    **Version history.** v1 (2026-12): the metrics gain the graded safety per kind (excess,
    largest excess, violated share of robot-periods), clean success within a 5 % band and
    the return; `input` leaves the safety totals, the reward's violation term and `cost`
    (it is clipped before the simulator); a failure prices the rest of the episode (ending
    early never pays); `vehicle_speed`'s value is the faster axis's
    fraction beyond its limit; the infos are flat numbers with the same keys at `reset`
    and every step, `episode_end` a code (docs/environment.md, "From v0 to v1"). v0 is
    no longer registered (its numbers are not comparable). v0 (2026-11): first version;
    the `comm` option added later in 2026-11 (default off).
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
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.render_mode = render_mode
        setup = resolve(scenario, overrides)
        self._engine = ScalarEngine(setup.scenario, setup.internal_wrench_every > 0)
        self._core = EnvCore(setup, self._engine, None, [setup.scenario.seed])
        self.n = n = setup.n_agents
        self.possible_agents = [f"uvms_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.comm = setup.comm  # the acoustic channel's settings (None: off)
        self.observation_spaces = {
            a: observation_space(setup.priors, setup.comm) for a in self.possible_agents
        }
        self.action_spaces = {a: action_space(setup.comm) for a in self.possible_agents}
        self.observation_structure = observation_structure(setup.priors, setup.comm)
        self.state_structure = state_structure(n)
        size = self.state_structure["time_fraction"].stop
        self.state_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self._path: list[np.ndarray] = []
        self._renderer: Any = None
        self._infos = InfoLayout(self._core.task.constraints, self._core.task.reward_terms)
        self.info_keys = self._infos.keys
        self.diverged_reason = ""

    # -- public views ------------------------------------------------------------------
    @property
    def scenario(self) -> Scenario:
        return self._engine.scenario

    @property
    def sim(self) -> Simulator:
        """The truth simulator (global information: never feed it to a policy)."""
        return self._engine.sim

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[self._agent(agent)]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[self._agent(agent)]

    def state(self) -> np.ndarray:
        return self._core.state()

    # -- episode -----------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode (``options`` is accepted and unused)."""
        if seed is not None:
            self._core.seed([0], [RESET_SEED.check("seed", seed)])
        self._core.reset([0])
        self.agents = self.possible_agents[:]
        self._path = [self._engine.object_pose(...)[:3].copy()]
        self.diverged_reason = ""
        return self._observations(), self._infos.reset(self.possible_agents)

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
        core = self._core
        out, diverged = core.step(self._parse_actions(actions))
        terminated, truncated = bool(out.terminated), bool(out.truncated)
        reward = float(out.reward)
        if self.render_mode is not None:
            self._path.append(self._engine.object_pose(...)[:3].copy())
        agents = self.possible_agents
        terms = [float(v) for v in out.terms.values()]
        rows = (agents, out.cost.tolist(), out.constraint_values.tolist(), terms)
        if terminated or truncated:
            (end,), (metrics,), (reason,) = core.ended([0], out, diverged)
            self.diverged_reason = reason
            infos = self._infos.step(*rows, end, bool(reason), metrics)
            self.agents = []
        else:
            infos = self._infos.step(*rows)
        return (
            self._observations(),
            dict.fromkeys(agents, reward),
            dict.fromkeys(agents, terminated),
            dict.fromkeys(agents, truncated),
            infos,
        )

    def _observations(self) -> dict[str, np.ndarray]:
        obs = self._core.view(...)
        return {a: obs[i] for i, a in enumerate(self.possible_agents)}

    def observe(self) -> dict[str, np.ndarray]:
        """Observations of the simulator's current state, e.g. after ``sim.set_state`` in a
        replay or a test. Measures like a step (draws sensor noise, may advance the
        robots' waypoint sequencers) but does not advance time or touch the reward."""
        self._core.refresh_observations(..., [0], None)
        return self._observations()

    def constraint_values(self) -> dict[str, dict[str, float]]:
        """Constraint values of the current true state (zero actions), per agent: for
        checks and tests; it does not advance the episode."""
        rows = self._core.constraint_values().tolist()
        names = self._core.task.constraints
        return {
            a: dict(zip(names, rows[i], strict=True)) for i, a in enumerate(self.possible_agents)
        }

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            warnings.warn(
                "render() called with render_mode=None; pass render_mode='rgb_array' or "
                "'human' to the environment",
                stacklevel=2,
            )
            return None
        scenario, sim = self.scenario, self.sim
        if self._renderer is None or self._renderer.scenario is not scenario:
            from uvms_env.env.render import Renderer

            self.close()
            self._renderer = Renderer(scenario, sim.object.segments)
        st = sim.state
        frame = self._renderer.frame(st.q, st.x_O, np.array(self._path), st.t)
        if self.render_mode == "rgb_array":
            return frame
        self._renderer.show(frame)
        return None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- copies ------------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """Pickles (and deep copies) hold the current geometry's compiled objects and the
        episode's state; the copy rebuilds its compiled functions from the disk cache and
        continues the same episode bit for bit. A window is no state."""
        return {**self.__dict__, "_renderer": None}

    def __copy__(self) -> CoopTransportEnv:
        """An independent copy: a shallow one would share the simulator."""
        return copy.deepcopy(self)

    # -- internals ---------------------------------------------------------------------
    def _agent(self, agent: str) -> str:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents: {self.possible_agents}")
        return agent

    def _parse_actions(self, actions: Mapping[str, Any]) -> np.ndarray:
        """(N, A) float64 checked actions (A = 8, or the channel's ``action_size``);
        ValueError naming the agent otherwise."""
        size = self._core.action_size
        if type(actions) is not dict and not isinstance(actions, Mapping):  # dict: fast
            raise ValueError(
                f"actions must be a dict agent -> array of shape ({size},), got {type(actions)}"
            )
        try:  # fast path: real (float or int) rows of shape (A,), one conversion for all
            rows = [np.asarray(actions[agent]) for agent in self.possible_agents]
        except (KeyError, ValueError, TypeError):
            rows = None
        if rows is None or not all(
            [r.dtype.kind in ACTION_KINDS and r.shape == (size,) for r in rows]
        ):
            self._explain_bad_actions(actions)
        if len(actions) != self.n:
            unknown = sorted(set(actions) - set(self._index), key=str)
            raise ValueError(
                f"actions for unknown agent(s) {unknown}; agents: {self.possible_agents}"
            )
        return self._core.check_actions(np.array(rows, dtype=float))

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
            size = self._core.action_size
            if arr.shape != (size,):
                hint = self._core.comm_hint() if self.comm is not None else ""
                raise ValueError(
                    f"action of agent {agent!r} must have shape ({size},), got {arr.shape}{hint}"
                )
        raise ValueError("actions could not be read")  # not reached: some agent is wrong


def parallel_env(
    scenario: str | Scenario = "paper", render_mode: str | None = None, **overrides: Any
) -> CoopTransportEnv:
    """The cooperative transport environment (see ``CoopTransportEnv``)."""
    return CoopTransportEnv(scenario, render_mode, **overrides)
