"""Policy sources for the evaluator: ``--policy NAME[:ARG]`` to a per-agent factory.

Names: the expert's variants (``nmpc``, ``nmpc:ipopt``, ``nmpc:paper``, ``nmpc:comm``;
``nmpc:central`` is a *team* policy, ``PolicySource.team``), the trivial rungs ``random``,
``zero`` and ``prior`` (the residual priors with a zero residual),
``module:factory``, the saved networks of ``baselines.registry.LOADERS`` and any of them
with ``+filter``. Reference: docs/evaluation.md.

May import: numpy, ``uvms_env``, ``nmpc_expert`` (inside functions),
``baselines.loaders.saved`` (the priors around a network: the ``prior`` rung) and
``baselines.registry`` (whose loaders are imported on demand).
"""

from __future__ import annotations

import ast
import importlib
import json
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy
from baselines.registry import LOADERS, loader
from uvms_env.dynamics import NU
from uvms_env.policy import AgentSpec, Policy, PolicyFactory
from uvms_env.robot.priors import Priors
from uvms_env.team_policy import FULL_INFORMATION, LOCAL_INFORMATION, TeamPolicyFactory

TALK_OPTION = "comm"  # nmpc:comm, the expert that talks over the channel
CARD_FILE = "info.json"  # a committed model's card
FILTER_SUFFIX = "+filter"


class RandomPolicy:
    """Uniform random normalized actions from its own seeded stream."""

    def __init__(self, spec: AgentSpec, seed: int) -> None:
        self._seed = (seed, spec.index)
        self.stats: dict[str, Any] = {}
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self._seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self._rng.uniform(-1.0, 1.0, 8).astype(np.float32)


class ZeroPolicy:
    """No input at all: the team drifts under weight, buoyancy and current."""

    def __init__(self, spec: AgentSpec) -> None:
        del spec
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(8, dtype=np.float32)


#: The trivial rung ``prior``: the residual action's priors with a zero residual: a_ss and
#: the joint hold of the first from-scratch runs (MAPPO, 2026-11-27; ``ppo:scratch`` now
#: starts from a_ss without the hold, docs/results/from-scratch.md).
PRIOR = Priors(
    action_mode="residual", observation_mode="features", hold_stiffness=0.5, hold_damping=1.0
)


class PriorPolicy(LoadedPolicy):
    """The priors alone: a learned rung's starting point (its network's output zero)."""

    KIND = "prior"

    def __init__(self, spec: AgentSpec) -> None:
        super().__init__(spec, PRIOR)

    def decide(self, x: np.ndarray) -> np.ndarray:
        return np.zeros(NU, np.float32)

    def batch_key(self) -> Hashable | None:
        return self.stateless_key(PRIOR)

    def decide_many(self, x: np.ndarray) -> np.ndarray:
        return np.zeros((len(x), NU), np.float32)


def nmpc_options(arg: str | None) -> list[str]:
    """The options of ``nmpc:OPTIONS``: split at the commas outside brackets, so that a
    tuple VALUE keeps its own (``vehicle_speed_fraction=(1.0, 0.8)``)."""
    text, parts, depth, start = arg or "", [], 0, 0
    for i, char in enumerate(text):
        depth += (char in "([{") - (char in ")]}")
        if char == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    return [*parts, text[start:]]


def _nmpc(arg: str | None, seed: int) -> PolicyFactory:
    """``nmpc[:OPTIONS]``, OPTIONS comma-separated: a solver (rti, ipopt), a controller
    (observer, paper) and/or settings ``NAME=VALUE`` (``nmpc_expert.NMPCSettings``' fields,
    VALUE a Python literal), e.g. ``nmpc:paper``, ``nmpc:ipopt``,
    ``nmpc:goal_integral_angle_limit=0.3``."""
    from nmpc_expert import (  # the expert is optional at import time
        CONTROLLERS,
        make_policy,
        make_talking_policy,
    )

    solver, controller, talk = "rti", None, False
    settings: dict[str, Any] = {}
    for option in nmpc_options(arg):
        if "=" in option:  # VALUE a Python literal (0.3, None, (1.0, 0.8)), else the text
            name, value = (part.strip() for part in option.split("=", 1))
            try:
                settings[name] = ast.literal_eval(value)
            except (ValueError, SyntaxError):
                settings[name] = value
        elif option in ("rti", "ipopt"):
            solver = option
        elif option in CONTROLLERS:
            controller = option
        elif option == TALK_OPTION:
            talk = True
        elif option:
            raise ValueError(
                f"unknown nmpc option {option!r}: use rti, ipopt, {TALK_OPTION}, one of "
                f"{CONTROLLERS} or NAME=VALUE settings (or nmpc:central alone: the "
                "centralized team policy)"
            )
    if talk:
        if solver != "rti" or controller not in (None, "observer"):
            raise ValueError(
                f"nmpc:{TALK_OPTION} shares the disturbance observer's estimate: it runs the "
                "observer controller with rti only"
            )
        return make_talking_policy(solver, **settings)
    return make_policy(solver, controller, **settings)


def _saved(name: str, arg: str | None, seed: int) -> PolicyFactory:
    """A saved network: its loader (``baselines.registry.LOADERS``) finds it now."""
    return loader(name).factory(name, arg)


# team policies (``uvms_env.team_policy``): name -> the option of ``nmpc`` that selects one
TEAM_OPTIONS = {"nmpc": "central"}
BUILTIN: dict[str, Callable[[str | None, int], PolicyFactory]] = {
    "nmpc": _nmpc,
    "random": lambda arg, seed: lambda spec: RandomPolicy(spec, seed),
    "zero": lambda arg, seed: ZeroPolicy,
    "prior": lambda arg, seed: PriorPolicy,
    **{name: partial(_saved, name) for name in LOADERS},
}


@dataclass(frozen=True)
class PolicySource:
    """A parsed ``--policy`` argument: a label for tables and a way to build factories;
    ``filtered``: wrapped in the safety filter (suffix ``+filter``)."""

    label: str
    name: str
    arg: str | None
    filtered: bool = False

    @property
    def team(self) -> bool:
        """A team policy (full information: one controller for every robot from the
        global state), played with ``uvms_env.episode.play_team``."""
        return self.arg is not None and TEAM_OPTIONS.get(self.name) == self.arg

    @property
    def information(self) -> str:
        """``"full"`` for a team policy (the full-information reference), else ``"local"``."""
        return FULL_INFORMATION if self.team else LOCAL_INFORMATION

    @staticmethod
    def parse(text: str) -> PolicySource:
        base = text.removesuffix(FILTER_SUFFIX)
        filtered = base != text
        name, _, arg = base.partition(":")
        if name in BUILTIN:
            source = PolicySource(text, name, arg or None, filtered)
            if source.team and filtered:
                raise ValueError(
                    f"{text!r}: the safety filter wraps per-robot policies; {base} is a team "
                    "policy (full information)"
                )
            return source
        if arg and "." in name:  # package.module:factory
            return PolicySource(text, "module", base, filtered)
        known = ", ".join(sorted(BUILTIN))
        raise ValueError(
            f"unknown policy {text!r}: use one of {known}, or package.module:factory, "
            f"each optionally with the suffix {FILTER_SUFFIX}"
        )

    def factory(self, episode_seed: int) -> PolicyFactory:
        """The per-agent factory for one episode (random policies are seeded by it)."""
        if self.team:
            raise TypeError(
                f"{self.label} is a team policy (full information); build it with "
                "team_factory() and play it with uvms_env.episode.play_team"
            )
        if self.name == "module":
            module, _, attr = self.arg.partition(":")  # type: ignore[union-attr]
            try:
                inner = getattr(importlib.import_module(module), attr)
            except (ImportError, AttributeError) as exc:
                raise ValueError(f"cannot import policy factory {module}:{attr}: {exc}") from exc
        else:
            inner = BUILTIN[self.name](self.arg, episode_seed)
        if not self.filtered:
            return inner
        from nmpc_expert import make_filter  # the expert is optional at import time

        return make_filter(inner)

    def card(self) -> dict[str, Any] | None:
        """The model card (``info.json`` beside the saved item) of a saved network; None
        for the controllers, the trivial rungs and a run folder without one."""
        if self.name not in LOADERS:
            return None
        saved = loader(self.name).locate(self.name, self.arg)
        path = (saved if saved.is_dir() else saved.parent) / CARD_FILE
        return json.loads(path.read_text()) if path.exists() else None

    def build_once(self, env: Any, seed: int) -> None:
        """Build this source's policy for robot 0 of ``env`` (a team source: its team
        policy), as an episode on ``env`` would: the saved network found and read, the
        expert's solver built. A source that cannot be loaded fails here, before any
        episode, raising what its loader raises."""
        if self.team:
            self.team_factory(seed)(env.scenario)
            return
        spec = AgentSpec.from_scenario(env.scenario, 0, getattr(env, "comm", None))
        check_policy(self.factory(seed)(spec))

    def team_factory(self, episode_seed: int) -> TeamPolicyFactory:
        """The team policy's factory (``team`` sources only)."""
        if not self.team:
            raise TypeError(f"{self.label} is a per-robot policy; use factory()")
        from nmpc_expert import make_central_policy  # the expert is optional at import time

        return make_central_policy()  # ``nmpc:central``: no further options


def check_policy(policy: Policy) -> None:
    if not isinstance(policy, Policy):
        raise TypeError(f"{type(policy).__name__} does not implement reset(), act(obs) and stats")
