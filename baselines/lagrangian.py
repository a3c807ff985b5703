"""Constraint-aware training for every PPO trainer: a per-robot constraint cost and a
Lagrange multiplier on it (PPO-Lagrangian, Ray, Achiam and Amodei 2019), independent of
the RL library:

    lambda <- clip(lambda + lr (J_c - d), 0, lambda_max),

J_c the mean cost per robot of the episodes that ended in the rollout and d the cost
limit per episode; ``lr = 0`` is a fixed penalty. Costs ``count`` and ``magnitude``
(``SCALES``): docs/rl.md. A trainer calls ``Lagrangian.penalize`` where its rewards are
made and ``Lagrangian.end_rollout`` once per rollout. Written here because the RL
libraries have no constrained RL and the safe-RL ones (OmniSafe, safety-gymnasium) bring
their own environment loop and pins.

May import: numpy and ``uvms_env.task.constraints``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from uvms_env.models import load_parameters
from uvms_env.task.constraints import CONSTRAINTS, SAFETY_CONSTRAINTS, constraint_scales

COSTS = ("count", "magnitude")


# one unit of normalized cost is a violation by the whole limit (``constraint_scales``)
SCALES = np.array(constraint_scales(load_parameters()))
# the kinds the cost sums: the safety kinds (``input`` is clipped before the simulator)
COUNTED = np.array([c in SAFETY_CONSTRAINTS for c in CONSTRAINTS])


@dataclass
class CostSettings:
    """``kind`` of cost, the starting multiplier, the cost limit d per episode and robot,
    the multiplier's learning rate (0: a fixed penalty) and its ceiling."""

    kind: str = "magnitude"
    multiplier: float = 0.1
    cost_limit: float = 0.0
    lr: float = 0.0
    max_multiplier: float = 100.0

    def __post_init__(self) -> None:
        if self.kind not in COSTS:
            raise ValueError(f"cost must be one of {COSTS}, got {self.kind!r}")
        for name in ("multiplier", "cost_limit", "lr", "max_multiplier"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def magnitude_cost(g: np.ndarray) -> np.ndarray:
    """(..., 8) constraint values -> (...) the safety kinds' normalized positive parts
    summed."""
    return (np.maximum(np.asarray(g, dtype=np.float64), 0.0) / SCALES)[..., COUNTED].sum(-1)


class Lagrangian:
    """The multiplier and the per-robot episode costs of one training run.

    ``penalize(g, count, done)``: R robots' (R, 8) constraint values and (R,) violation
    counts (the environment's ``cost``) this step, and (R,) their episode ended -> (R,)
    costs (the caller subtracts ``multiplier * cost``); ``end_rollout`` takes the dual step
    from the episodes that ended since the last one."""

    def __init__(self, settings: CostSettings, robots: int) -> None:
        self.settings = settings
        self.multiplier = float(settings.multiplier)
        self._episode = np.zeros(robots)
        self._finished: list[float] = []

    def reset(self) -> None:
        self._episode[:] = 0.0

    def record(self, cost: np.ndarray, done: np.ndarray) -> None:
        """Adds the step's (R,) costs; closes the episodes where ``done``."""
        self._episode += cost
        if np.any(done):
            ended = np.flatnonzero(done)
            self._finished.extend(self._episode[ended].tolist())
            self._episode[ended] = 0.0

    def take_finished(self) -> list[float]:
        """The costs of the episodes ended since the last call, handed over: where the
        episodes run elsewhere (RLlib's env runners), the driver's ``Lagrangian`` ``add``s
        them before its ``end_rollout``."""
        finished, self._finished = self._finished, []
        return finished

    def add(self, episode_costs: list[float]) -> None:
        self._finished.extend(float(c) for c in episode_costs)

    def penalize(self, g: Any, count: Any, done: np.ndarray) -> np.ndarray:
        """``g`` and ``count`` are only read for their kind of cost (the other may be
        None)."""
        robots = len(self._episode)
        if self.settings.kind == "magnitude":
            cost = magnitude_cost(np.asarray(g).reshape(robots, -1))
        else:
            cost = np.asarray(count, dtype=np.float64).reshape(robots)
        self.record(cost, np.asarray(done).reshape(-1))
        return cost

    def end_rollout(self) -> float | None:
        """One dual step from the episodes ended since the last call; returns their mean
        cost (None, and no step, when none ended)."""
        if not self._finished:
            return None
        mean = float(np.mean(self._finished))
        self._finished.clear()
        s = self.settings
        self.multiplier = float(
            np.clip(self.multiplier + s.lr * (mean - s.cost_limit), 0.0, s.max_multiplier)
        )
        return mean
