"""Constraint-aware training for every PPO trainer: a per-robot constraint cost and a
Lagrange multiplier on it (PPO-Lagrangian, Ray, Achiam and Amodei 2019), independent of
the RL library:

    lambda <- clip(lambda + lr (J_c - d), 0, lambda_max),

J_c the mean cost per robot of the episodes that ended in the rollout and d the cost
limit per episode, or (``limit_per="period"``) J_c the mean of each such episode's cost
over the periods it covers and d a limit per period, the same for a 100-period and a
3,000-period episode; ``lr = 0`` is a fixed penalty. Costs ``count`` and ``magnitude``
(``SCALES``): docs/rl.md. Per robot and period either costs at most ``PERIOD_CAP`` (every
safety kind violated; a kind's magnitude counts up to one whole limit), and an episode
that ends in failure also costs ``PERIOD_CAP`` for each period left to its time limit:
without it, ending an episode early stops its cost and pays under the multiplier (the
from-scratch runs on the distribution learned to: most of their training episodes
diverged). A trainer calls ``Lagrangian.penalize`` where its rewards are
made and ``Lagrangian.end_rollout`` once per rollout. Written here because the RL
libraries have no constrained RL and the safe-RL ones (OmniSafe, safety-gymnasium) bring
their own environment loop and pins.

May import: numpy, ``uvms_env.models``, ``uvms_env.task.constraints`` and
``uvms_env.env.infos`` (the episode ends' codes).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from uvms_env.env.infos import EPISODE_END_NAMES
from uvms_env.models import load_parameters
from uvms_env.task.constraints import CONSTRAINTS, SAFETY_CONSTRAINTS, constraint_scales

COSTS = ("count", "magnitude")
LIMIT_UNITS = ("episode", "period")  # what the cost limit d is per


# one unit of normalized cost is a violation by the whole limit (``constraint_scales``)
SCALES = np.array(constraint_scales(load_parameters()))
# the kinds the cost sums: the safety kinds (``input`` is clipped before the simulator)
COUNTED = np.array([c in SAFETY_CONSTRAINTS for c in CONSTRAINTS])
PERIOD_CAP = float(len(SAFETY_CONSTRAINTS))  # the most either cost takes per robot-period
FAILURES = ("diverged", "collision", "constraint")  # the ends ``periods_left`` prices


@dataclass
class CostSettings:
    """``kind`` of cost, the starting multiplier, the cost limit d per robot and
    ``limit_per`` (episode or period), the multiplier's learning rate (0: a fixed penalty)
    and its ceiling."""

    kind: str = "magnitude"
    multiplier: float = 0.1
    cost_limit: float = 0.0
    lr: float = 0.0
    max_multiplier: float = 100.0
    limit_per: str = "episode"

    def __post_init__(self) -> None:
        if self.kind not in COSTS:
            raise ValueError(f"cost must be one of {COSTS}, got {self.kind!r}")
        if self.limit_per not in LIMIT_UNITS:
            raise ValueError(f"limit_per must be one of {LIMIT_UNITS}, got {self.limit_per!r}")
        for name in ("multiplier", "cost_limit", "lr", "max_multiplier"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def magnitude_cost(g: np.ndarray) -> np.ndarray:
    """(..., 8) constraint values -> (...) the safety kinds' normalized positive parts, each
    up to one whole limit, summed."""
    excess = np.maximum(np.asarray(g, dtype=np.float64), 0.0) / SCALES
    return np.minimum(excess, 1.0)[..., COUNTED].sum(-1)


def periods_left(info: dict[str, Any], max_cycles: int | None = None) -> int:
    """The periods left to the time limit of a robot's episode that ended in failure on
    this step (0 otherwise: running, a success, a time-out), from its info (the end's code,
    the episode's ``episode_steps``, and ``max_cycles`` there or given): what its cost also
    pays."""
    if EPISODE_END_NAMES[int(info.get("episode_end", 0))] not in FAILURES:
        return 0
    cap = int(info["max_cycles"] if max_cycles is None else max_cycles)
    return max(cap - int(info["episode_steps"]), 0)


class Lagrangian:
    """The multiplier and the per-robot episode costs of one training run.

    ``penalize(g, count, done, left)``: R robots' (R, 8) constraint values and (R,)
    violation counts (the environment's ``cost``) this step, (R,) their episode ended and
    (R,) the periods left to the time limit of an episode that ended in failure (0
    otherwise) -> (R,) costs (the caller subtracts ``multiplier * cost``); ``end_rollout``
    takes the dual step from the episodes that ended since the last one."""

    def __init__(self, settings: CostSettings, robots: int) -> None:
        self.settings = settings
        self.multiplier = float(settings.multiplier)
        self._episode = np.zeros(robots)
        self._periods = np.zeros(robots)
        self._finished: list[tuple[float, float]] = []  # (cost, periods it covers)

    def reset(self) -> None:
        self._episode[:] = 0.0
        self._periods[:] = 0.0

    def record(self, cost: np.ndarray, done: np.ndarray, left: Any = None) -> None:
        """Adds the step's (R,) costs (and the (R,) periods a failure prices, if any);
        closes the episodes where ``done``."""
        self._episode += cost
        self._periods += 1.0 if left is None else 1.0 + np.asarray(left, dtype=np.float64)
        if np.any(done):
            ended = np.flatnonzero(done)
            pairs = zip(self._episode[ended].tolist(), self._periods[ended].tolist(), strict=True)
            self._finished.extend(pairs)
            self._episode[ended] = 0.0
            self._periods[ended] = 0.0

    def take_finished(self) -> list[tuple[float, float]]:
        """The (cost, periods covered) of the episodes ended since the last call, handed
        over: where the episodes run elsewhere (RLlib's env runners), the driver's
        ``Lagrangian`` ``add``s them before its ``end_rollout``."""
        finished, self._finished = self._finished, []
        return finished

    def add(self, episodes: list[tuple[float, float]]) -> None:
        self._finished.extend((float(c), float(n)) for c, n in episodes)

    def penalize(self, g: Any, count: Any, done: np.ndarray, left: Any = None) -> np.ndarray:
        """``g`` and ``count`` are only read for their kind of cost (the other may be
        None); ``left`` None: no failure."""
        robots = len(self._episode)
        if self.settings.kind == "magnitude":
            cost = magnitude_cost(np.asarray(g).reshape(robots, -1))
        else:
            cost = np.asarray(count, dtype=np.float64).reshape(robots)
        if left is not None:
            left = np.asarray(left, dtype=np.float64).reshape(robots)
            cost = cost + PERIOD_CAP * left
        self.record(cost, np.asarray(done).reshape(-1), left)
        return cost

    def end_rollout(self) -> float | None:
        """One dual step from the episodes ended since the last call; returns their mean
        cost per episode (None, and no step, when none ended). The step compares the limit
        with that mean, or (``limit_per="period"``) with the mean of each episode's cost
        over the periods it covers."""
        if not self._finished:
            return None
        costs, periods = np.array(self._finished).T
        self._finished.clear()
        s = self.settings
        measured = float(np.mean(costs / periods if s.limit_per == "period" else costs))
        self.multiplier = float(
            np.clip(self.multiplier + s.lr * (measured - s.cost_limit), 0.0, s.max_multiplier)
        )
        return float(np.mean(costs))
