"""The environments' keywords and what they resolve to, for ``parallel_env`` and ``VectorEnv``.

``resolve`` checks every keyword against one typed table (``SCENARIO_OVERRIDES`` of
``uvms_env.scenarios.overrides`` and ``ENV_OPTIONS`` here, plus a caller's own), builds the
scenario the environment starts on and decides whether ``reset(seed=s)`` sets a seeded
family's geometry: one rule for both environments. ``geometry`` gives the scenario of a
geometry seed, from the geometry bank (``uvms_env.scenarios.bank``), so that the single
and the batched environment play the same geometry for the same seed.

May import: numpy, gymnasium (spaces), ``uvms_env.dynamics`` (sizes), ``uvms_env.scenarios``
and the ``env`` modules of the priors, the observation layout and the reward weights.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from gymnasium import spaces

from uvms_env.dynamics import NQ, NU
from uvms_env.robot.channel import ChannelSettings, block_bounds, channel_settings
from uvms_env.robot.observation import OBSERVATION_SIZE, OBSERVATION_STRUCTURE, observation_bounds
from uvms_env.robot.priors import (
    ACTION_MODES,
    DEFAULT_RESIDUAL_SCALE,
    DEFAULT_SETPOINT_JOINT_GAIN,
    DEFAULT_SETPOINT_TIME,
    OBSERVATION_MODES,
    Priors,
)
from uvms_env.scenarios import FAMILIES, SEEDED_FAMILIES, Scenario, make, replace
from uvms_env.scenarios.bank import GeometryBank
from uvms_env.scenarios.families import default_agents
from uvms_env.scenarios.overrides import (
    FAMILY_OPTIONS,
    SCENARIO_OVERRIDES,
    Option,
    describe_options,
    validate_options,
    validate_overrides,
)
from uvms_env.task.conditions import ConditionDraws, condition_draws
from uvms_env.task.reward import RewardWeights

CONSTRAINT_MODES = ("penalize", "terminate")
# The environment's own keyword options (the scenario overrides: SCENARIO_OVERRIDES).
ENV_OPTIONS: dict[str, Option] = {
    "constraint_mode": Option("choice", "soft-constraint violations", choices=CONSTRAINT_MODES),
    "max_cycles": Option("int", "truncation; None: the scenario's max_steps", low=1, optional=True),
    "reward_weights": Option("weights", "overrides of RewardWeights", optional=True),
    "reseed_geometry": Option("bool", "reset(seed=s) also sets a seeded family's geometry"),
    "internal_wrench_every": Option("int", "internal wrench metric period, 0: never", low=0),
    "extra_reward_terms": Option(
        "functions", "extra reward terms fn(s, xp) -> (K,) (uvms_env.task.rules)", optional=True
    ),
    "extra_constraints": Option(
        "functions", "extra constraints fn(s, xp) -> g (K, N) (uvms_env.task.rules)", optional=True
    ),
    "action_mode": Option(
        "choice",
        "torque: normalized inputs; residual: around own a_ss; setpoint: velocity set-points "
        "(normalized by their limits) tracked around own a_ss",
        choices=ACTION_MODES,
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
    "setpoint_time": Option(
        "float",
        "setpoint mode: the vehicle loop's time constant on the robot's own inertia, s",
        low=0.05,
        high=10.0,
    ),
    "setpoint_joint_gain": Option(
        "float",
        "setpoint mode: normalized joint torque per joint-rate error of one limit",
        low=0.0,
        high=1.0,
        low_open=True,
    ),
    "comm": Option(
        "comm",
        "acoustic channel: None/'off' (silent team) or a preset (uvms_env.robot.channel)",
        optional=True,
    ),
    "randomize": Option(
        "draws",
        "per-episode draws of the current preset and the mismatch (uvms_env.task.conditions)",
        optional=True,
    ),
}
RESET_SEED = Option("int", "reset's seed", low=0, optional=True)
# Seeded-family scenarios kept per geometry seed (each costs an IPOPT solve to build).
GEOMETRY_CACHE_SIZE = 32


@dataclass
class EnvSetup:
    """What an environment's keywords resolve to (``resolve``)."""

    family: str | None  # None: a built Scenario was given
    overrides: dict[str, Any]  # checked scenario overrides
    options: dict[str, Any]  # checked environment options
    own: dict[str, Any]  # the caller's own checked options (e.g. the vector env's)
    seeded: bool  # reset(seed=s) sets geometry s (a seeded family with reseed_geometry)
    n_agents: int
    scenario: Scenario = field(init=False)  # the geometry the environment starts on
    reward_weights: RewardWeights = field(init=False)
    priors: Priors = field(init=False)
    comm: ChannelSettings | None = field(init=False)  # the acoustic channel (None: off)
    draws: ConditionDraws | None = field(init=False)  # per-episode conditions (None: fixed)

    def __post_init__(self) -> None:
        self.reward_weights = RewardWeights.from_mapping(self.options.get("reward_weights"))
        self.priors = priors_of(self.options)
        self.comm = channel_settings(self.options.get("comm"))
        self.draws = condition_draws(self.options.get("randomize"))
        self._bank = (
            GeometryBank(self.family, self.n_agents, overrides=self.overrides)  # type: ignore[arg-type]
            if self.seeded
            else None
        )
        self._by_seed: dict[int, Scenario] = {}

    @property
    def constraint_mode(self) -> str:
        return self.options.get("constraint_mode", "penalize")

    @property
    def internal_wrench_every(self) -> int:
        return self.options.get("internal_wrench_every", 1)

    @property
    def extensions(self) -> dict[str, Any]:
        return {k: self.options.get(k) for k in ("extra_reward_terms", "extra_constraints")}

    def max_cycles(self) -> int:
        value = self.options.get("max_cycles")
        return int(self.scenario.max_steps) if value is None else int(value)

    def geometry(self, seed: int) -> Scenario:
        """The scenario of geometry seed ``seed`` with the overrides (seeded families):
        ``make(family, seed=seed, n_agents=N, **overrides)``, read from the geometry bank."""
        if seed not in self._by_seed:
            assert self._bank is not None, "geometry seeds need a seeded family"
            self._by_seed[seed] = self._bank.get(seed).scenario_with(self.overrides)
        return self._by_seed[seed]

    def prebuild(self, seeds: range) -> int:
        """Build the missing bank geometries of ``seeds`` now, with a progress bar, rather
        than one by one in the episodes' resets; returns how many were built."""
        assert self._bank is not None, "geometry seeds need a seeded family"
        return self._bank.fill(seeds, progress=True)

    def navigation(self, scenario: Scenario) -> np.ndarray | None:
        """The bank's navigation parameters of a seeded geometry (None: not in the bank)."""
        if self._bank is None or scenario.seed is None:
            return None
        return self._bank.get(scenario.seed).navigation


def resolve(
    scenario: str | Scenario,
    keywords: Mapping[str, Any],
    default_seed: int | None = None,
    extra: Mapping[str, Option] | None = None,
    extra_name: str = "",
) -> EnvSetup:
    """An environment's ``scenario`` and keywords checked and resolved. The starting
    geometry of a seeded family is the bank's for the ``seed`` override, or for
    ``default_seed`` without one (None: a fresh random draw)."""
    overrides, options, own = split_keywords(keywords, extra, extra_name)
    if isinstance(scenario, Scenario):
        for key in FAMILY_OPTIONS:
            if key in overrides:
                raise ValueError(f"{key} cannot be overridden on a built Scenario")
        setup = EnvSetup(None, overrides, options, own, False, scenario.n_agents)
        setup.scenario = replace(scenario, **overrides) if overrides else scenario
        return setup
    if not isinstance(scenario, str) or scenario not in FAMILIES:
        raise ValueError(
            f"scenario must be a family name {sorted(FAMILIES)} or a Scenario, got {scenario!r}"
        )
    seeded = scenario in SEEDED_FAMILIES and options.get("reseed_geometry", True)
    seed = overrides.get("seed", default_seed)
    if seeded and seed is not None:
        n = int(overrides.get("n_agents", default_agents(scenario)))
        setup = EnvSetup(scenario, overrides, options, own, True, n)
        setup.scenario = setup.geometry(int(seed))
        return setup
    built = make_scenario(scenario, overrides)
    setup = EnvSetup(scenario, overrides, options, own, seeded, built.n_agents)
    setup.scenario = built
    return setup


def split_keywords(
    keywords: Mapping[str, Any], extra: Mapping[str, Option] | None = None, extra_name: str = ""
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """``keywords`` split into (scenario overrides, environment options, ``extra`` options),
    each checked against its table; an unknown keyword raises ValueError listing every
    allowed one."""
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


def priors_of(options: Mapping[str, Any]) -> Priors:
    """The action and observation modes among checked environment ``options``."""
    return Priors(
        options.get("action_mode", "torque"),
        options.get("observation_mode", "raw"),
        options.get("residual_scale", DEFAULT_RESIDUAL_SCALE),
        options.get("hold_stiffness", 0.0),
        options.get("hold_damping", 0.0),
        options.get("setpoint_time", DEFAULT_SETPOINT_TIME),
        options.get("setpoint_joint_gain", DEFAULT_SETPOINT_JOINT_GAIN),
    )


def observation_space(priors: Priors, comm: ChannelSettings | None = None) -> spaces.Box:
    """One robot's observation space: the raw layout's bounds, or unbounded features;
    with a channel, the inbox block's bounds after them."""
    if priors.observation_mode == "raw":
        low, high = observation_bounds()
    else:
        size = priors.observation_size
        low, high = np.full(size, -np.inf, np.float32), np.full(size, np.inf, np.float32)
    if comm is not None:
        b_low, b_high = block_bounds(comm)
        low, high = np.concatenate([low, b_low]), np.concatenate([high, b_high])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), low.shape, np.float32)


def action_space(comm: ChannelSettings | None = None) -> spaces.Box:
    """One robot's action space: 8 normalized inputs; with a channel, the send flag and
    the message after them (``uvms_env.robot.channel``)."""
    size = NU if comm is None else comm.action_size
    return spaces.Box(-1.0, 1.0, (size,), np.float32)


def observation_structure(priors: Priors, comm: ChannelSettings | None = None) -> dict[str, slice]:
    """Names and slices of the raw observation's fields; with a channel, ``messages``: the
    inbox block after the observation (raw or features)."""
    out = dict(OBSERVATION_STRUCTURE)
    if comm is not None:
        start = OBSERVATION_SIZE if priors.observation_mode == "raw" else priors.observation_size
        out["messages"] = slice(start, start + comm.block_size)
    return out


def state_structure(n: int) -> dict[str, slice]:
    """Names and slices of ``state()``: the true state, the team's waypoint, the time."""
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


def make_scenario(name: str, overrides: dict[str, Any]) -> Scenario:
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
