"""Policy sources for the evaluator: ``--policy NAME[:ARG]`` to a per-agent factory.

Known names: ``nmpc`` (the expert, ``nmpc:ipopt`` for its reference solver, ``nmpc:paper``
for the paper's controller without the disturbance observer, ``nmpc:comm`` for the expert
that talks over the acoustic channel, ``--comm PRESET``: ``nmpc_expert.comm``;
``nmpc:central``: the centralized NMPC, a *team* policy with full information, the bound of
the ladder, never a decentralized entry: ``PolicySource.team``), ``random`` (uniform
actions, seeded per episode and agent), ``zero`` (all inputs zero), and ``module:factory``
(a user's ``factory(spec) -> Policy`` importable as ``package.module:factory``),
``ppo:PATH`` / ``sac:PATH`` / ``recurrent_ppo:PATH`` (an SB3 or sb3-contrib run folder;
``ppo:pretrained`` the committed model), ``bc:PATH`` / ``dagger:PATH`` (a folder with
``policy.pt``; ``dagger:pretrained`` the committed clone), ``rllib:PATH`` (an RLlib run or
checkpoint) and ``torchrl:PATH`` (a run folder of ``--engine torchrl``: its ``actor.pt``).
Any of them with the suffix ``+filter`` (e.g. ``dagger:pretrained+filter``) runs inside the
expert's safety filter (``nmpc_expert.SafetyFilter``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.policy import AgentSpec, Policy, PolicyFactory
from uvms_env.team_policy import FULL_INFORMATION, LOCAL_INFORMATION, TeamPolicyFactory

PRETRAINED = Path(__file__).resolve().parent / "pretrained"
TALK_OPTION = "comm"  # nmpc:comm, the expert that talks over the channel
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


def _nmpc(arg: str | None, seed: int) -> PolicyFactory:
    """``nmpc[:OPTIONS]``, OPTIONS comma-separated: a solver (rti, ipopt) and/or a
    controller (observer, paper), e.g. ``nmpc:paper``, ``nmpc:ipopt``."""
    from nmpc_expert import (  # the expert is optional at import time
        CONTROLLERS,
        make_policy,
        make_talking_policy,
    )

    solver, controller, talk = "rti", None, False
    for option in (arg or "").split(","):
        if option in ("rti", "ipopt"):
            solver = option
        elif option in CONTROLLERS:
            controller = option
        elif option == TALK_OPTION:
            talk = True
        elif option:
            raise ValueError(
                f"unknown nmpc option {option!r}: use rti, ipopt, {TALK_OPTION} or one of "
                f"{CONTROLLERS} (or nmpc:central alone: the centralized team policy)"
            )
    if talk:
        if solver != "rti" or controller not in (None, "observer"):
            raise ValueError(
                f"nmpc:{TALK_OPTION} shares the disturbance observer's estimate: it runs the "
                "observer controller with rti only"
            )
        return make_talking_policy(solver)
    return make_policy(solver, controller)


def _random(arg: str | None, seed: int) -> PolicyFactory:
    return lambda spec: RandomPolicy(spec, seed)


def _zero(arg: str | None, seed: int) -> PolicyFactory:
    return ZeroPolicy


def _sb3(algo: str) -> Callable[[str | None, int], PolicyFactory]:
    def build(arg: str | None, seed: int) -> PolicyFactory:
        from baselines.rl.policy import SB3Policy, resolve_run

        folder = resolve_run(algo, arg)
        return lambda spec: SB3Policy(spec, algo, folder)

    return build


def cloned_path(method: str, arg: str | None) -> Path:
    """The ``policy.pt`` of ``bc:ARG`` / ``dagger:ARG``."""
    folder = Path(arg) if arg not in (None, "", "pretrained") else PRETRAINED / method
    path = folder if folder.suffix == ".pt" else folder / "policy.pt"
    if not path.exists():
        raise ValueError(f"no {method} policy at {path}")
    return path


def _cloned(method: str) -> Callable[[str | None, int], PolicyFactory]:
    def build(arg: str | None, seed: int) -> PolicyFactory:
        from baselines.imitation.policy import ClonedPolicy

        path = cloned_path(method, arg)
        return lambda spec: ClonedPolicy(spec, path)

    return build


def _user(module: str, attr: str) -> Callable[[str | None, int], PolicyFactory]:
    def build(arg: str | None, seed: int) -> PolicyFactory:
        try:
            factory = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"cannot import policy factory {module}:{attr}: {exc}") from exc
        return factory

    return build


def _rllib(arg: str | None, seed: int) -> PolicyFactory:
    from baselines.distributed.rllib_policy import factory  # Ray is optional

    return factory(arg)


def _torchrl(arg: str | None, seed: int) -> PolicyFactory:
    from baselines.rl.torchrl_policy import factory

    return factory(arg)


# team policies (``uvms_env.team_policy``): name -> the option of ``nmpc`` that selects one
TEAM_OPTIONS = {"nmpc": "central"}


def _central(arg: str | None, seed: int) -> TeamPolicyFactory:
    """``nmpc:central``: the centralized NMPC (a team policy; no further options)."""
    from nmpc_expert import make_central_policy  # the expert is optional at import time

    return make_central_policy()


BUILTIN: dict[str, Callable[[str | None, int], PolicyFactory]] = {
    "nmpc": _nmpc,
    "random": _random,
    "zero": _zero,
    "ppo": _sb3("ppo"),
    "sac": _sb3("sac"),
    "recurrent_ppo": _sb3("recurrent_ppo"),
    "bc": _cloned("bc"),
    "dagger": _cloned("dagger"),
    "rllib": _rllib,
    "torchrl": _torchrl,
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
        """``"full"`` for a team policy (a full-information bound), else ``"local"``."""
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
            inner = _user(module, attr)(None, episode_seed)
        else:
            inner = BUILTIN[self.name](self.arg, episode_seed)
        if not self.filtered:
            return inner
        from nmpc_expert import make_filter  # the expert is optional at import time

        return make_filter(inner)

    def team_factory(self, episode_seed: int) -> TeamPolicyFactory:
        """The team policy's factory (``team`` sources only)."""
        if not self.team:
            raise TypeError(f"{self.label} is a per-robot policy; use factory()")
        return _central(self.arg, episode_seed)


def check_policy(policy: Policy) -> None:
    if not isinstance(policy, Policy):
        raise TypeError(f"{type(policy).__name__} does not implement reset(), act(obs) and stats")
