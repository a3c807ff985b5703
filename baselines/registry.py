"""One registry of the RL libraries that train a shared policy and of the classes that
load saved policies.

``baselines.train --library NAME`` builds that library's trainer (a module with a
``Trainer``, ``baselines.runs.Trainer``); ``baselines.loaders.sources`` builds ``--policy
NAME:PATH`` with that name's loader (a ``baselines.loaders.saved.LoadedPolicy``). Both are
named here as strings and imported on demand: a library loads only when it is chosen.

May import: the standard library only (the modules it names are imported on demand).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any


@dataclass(frozen=True)
class Library:
    """An RL library: its trainer's module, the algorithms it trains and the ``--policy``
    name its runs load with (None: the algorithm's)."""

    trainer: str
    algos: tuple[str, ...]
    policy: str | None = None


LIBRARIES: dict[str, Library] = {
    "sb3": Library("baselines.rl.sb3_trainer", ("ppo", "sac", "recurrent_ppo")),
    "benchmarl": Library(
        "baselines.rl.benchmarl_trainer", ("mappo", "ippo", "masac"), policy="benchmarl"
    ),
    "rllib": Library("baselines.rl.rllib_trainer", ("ppo",), policy="rllib"),
}
DEFAULT_LIBRARY = "sb3"

_SB3 = "baselines.loaders.sb3_policy:SB3Policy"
_CLONE = "baselines.loaders.clone_policy:ClonedPolicy"
# ``--policy NAME[:PATH]`` of a saved network -> its loader (``module:Class``)
LOADERS: dict[str, str] = {
    **{algo: _SB3 for algo in LIBRARIES["sb3"].algos},
    "benchmarl": "baselines.loaders.benchmarl_policy:BenchMARLPolicy",
    "rllib": "baselines.loaders.rllib_policy:RLlibPolicy",
    "bc": _CLONE,
    "dagger": _CLONE,
    # DAgger clones named by teacher: student:pretrained (the full-information reference), :expert
    "student": _CLONE,
}


def library(name: str) -> Library:
    if name not in LIBRARIES:
        raise ValueError(f"unknown library {name!r}; expected one of {tuple(LIBRARIES)}")
    return LIBRARIES[name]


def trainer_module(name: str) -> ModuleType:
    """The library's trainer module: ``DEFAULTS`` (num_envs, geometry_pool),
    ``SEVERAL_TEAM_SIZES`` (whether one run takes several ``--n-agents``),
    ``add_arguments(group)``, ``check_options(settings, algo, args)`` (ValueError naming an
    option it cannot honour, before any work) and ``Trainer(run, algo, args)``
    (``baselines.runs.Trainer``)."""
    return importlib.import_module(library(name).trainer)


def loader(name: str) -> Any:
    """The ``LoadedPolicy`` class of ``--policy NAME:...``."""
    module, _, attr = LOADERS[name].partition(":")
    return getattr(importlib.import_module(module), attr)


def policy_spec(library_name: str, algo: str, folder: Path) -> str:
    """The evaluator's ``--policy`` spec of a policy that ``library_name`` saved in
    ``folder``."""
    return f"{library(library_name).policy or algo}:{folder}"
