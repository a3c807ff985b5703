"""The parallel environment's infos: per agent one flat dict of numbers, the same keys at
``reset`` and at every step, so that a tensor library carries them as they are (TorchRL's
``PettingZooWrapper`` builds its info spec from ``reset``'s infos and writes each step's
into it).

Per agent, in order (``info_keys``):

* ``cost``: the robot's violated safety constraints this period;
* ``constraint_<kind>``: its constraint values (g <= 0 holds), every kind and extra one;
* ``reward_<term>``: the shared reward's terms (the same for every agent);
* ``episode_end``: 0 while the episode runs, then the code of how it ended,
  ``EPISODE_END_NAMES[code]`` (1 success, 2 diverged, 3 collision, 4 constraint,
  5 max_cycles); ``diverged``: 1 when this step was refused (``env.diverged_reason``
  says why);
* the ended episode's metrics (``uvms_env.task.metrics.metric_keys``) on the step that
  ends it, zeros of their types on every other step (``metric_zeros``).

``episode_metrics(info)`` reads an ended episode's metrics back from one agent's info,
``constraint_values(info)``, ``reward_terms(info)`` and ``end_name(info)`` the step's parts
by name.
May import: ``uvms_env.task`` (metrics, rules).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from uvms_env.task.metrics import metric_keys, metric_zeros
from uvms_env.task.rules import EPISODE_ENDS

#: ``infos[agent]["episode_end"]``'s names by code: 0 while the episode runs.
EPISODE_END_NAMES = ("running", *EPISODE_ENDS)
CONSTRAINT_PREFIX, REWARD_PREFIX = "constraint_", "reward_"


def step_keys(constraints: Sequence[str], reward_terms: Sequence[str]) -> tuple[str, ...]:
    """The keys every step fills (``info_keys`` before the metrics)."""
    return (
        "cost",
        *(CONSTRAINT_PREFIX + k for k in constraints),
        *(REWARD_PREFIX + t for t in reward_terms),
        "episode_end",
        "diverged",
    )


def info_keys(constraints: Sequence[str], reward_terms: Sequence[str]) -> tuple[str, ...]:
    """Every key of an agent's info, in order (module docstring)."""
    return (*step_keys(constraints, reward_terms), *metric_keys(constraints))


def end_code(name: str) -> int:
    """The ``episode_end`` code of an end's name (``EPISODE_END_NAMES``)."""
    return EPISODE_END_NAMES.index(name)


def constraint_kinds(info: Mapping[str, Any]) -> list[str]:
    """The constraint kinds an agent's info carries, in order."""
    return [k.removeprefix(CONSTRAINT_PREFIX) for k in info if k.startswith(CONSTRAINT_PREFIX)]


def constraint_values(info: Mapping[str, Any]) -> dict[str, float]:
    """An agent's constraint values by kind (v0's ``info["constraint_values"]``)."""
    n = len(CONSTRAINT_PREFIX)
    return {k[n:]: v for k, v in info.items() if k.startswith(CONSTRAINT_PREFIX)}


def reward_terms(info: Mapping[str, Any]) -> dict[str, float]:
    """The shared reward's terms by name (v0's ``info["reward_terms"]``)."""
    n = len(REWARD_PREFIX)
    return {k[n:]: v for k, v in info.items() if k.startswith(REWARD_PREFIX)}


def end_name(info: Mapping[str, Any]) -> str:
    """How the episode ended by name, ``"running"`` while it runs."""
    return EPISODE_END_NAMES[int(info["episode_end"])]


def episode_metrics(info: Mapping[str, Any]) -> dict[str, Any] | None:
    """The ended episode's metrics in one agent's info (None while it runs)."""
    if not info.get("episode_end"):
        return None
    return {k: info[k] for k in metric_keys(constraint_kinds(info))}


class InfoLayout:
    """Builds the agents' infos of one environment: ``reset()`` zeros, ``step(...)`` the
    step's values over a zeroed copy, with an ended episode's metrics on top."""

    def __init__(self, constraints: Sequence[str], reward_terms: Sequence[str]) -> None:
        self.keys = info_keys(constraints, reward_terms)
        self.step_keys = step_keys(constraints, reward_terms)
        self._zeros: dict[str, Any] = dict.fromkeys(self.step_keys, 0.0)
        self._zeros.update(cost=0, episode_end=0, diverged=0, **metric_zeros(constraints))

    def reset(self, agents: Sequence[str]) -> dict[str, dict[str, Any]]:
        return {a: dict(self._zeros) for a in agents}

    def step(
        self,
        agents: Sequence[str],
        costs: Sequence[int],
        constraint_rows: Sequence[Sequence[float]],
        terms: Sequence[float],
        end: str | None = None,
        diverged: bool = False,
        metrics: Mapping[str, Any] | None = None,
    ) -> dict[str, dict[str, Any]]:
        """Each agent's info: its cost and constraint values, the shared terms, and (``end``
        the name of how the episode ended) the end's code and the episode's metrics."""
        tail = [end_code(end) if end else 0, int(diverged)]
        out = {}
        for agent, cost, g in zip(agents, costs, constraint_rows, strict=True):
            info = dict(self._zeros)
            info.update(zip(self.step_keys, [int(cost), *g, *terms, *tail], strict=True))
            if metrics is not None:
                info.update(metrics)
            out[agent] = info
        return out
