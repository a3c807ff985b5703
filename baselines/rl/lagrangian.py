"""Constraint-aware training: a per-robot constraint cost and a Lagrange multiplier on it.

PPO-Lagrangian (Ray, Achiam and Amodei 2019, "Benchmarking safe exploration in deep RL")
as a VecEnv wrapper and a callback, so that SB3's PPO itself stays unchanged: each robot's
reward becomes r - lambda c_i, where c_i is that robot's constraint cost this step, and
after each rollout lambda moves by gradient ascent on the dual,

    lambda <- clip(lambda + lr (J_c - d), 0, lambda_max),

J_c the mean cost per robot of the episodes that ended in the rollout and d the cost
limit per episode. With ``lr = 0`` it is a fixed penalty of weight lambda.

Costs (per robot, per step; the environment's constraint values g <= 0 hold):

* ``count``: the number of violated constraints (the environment's ``cost``). Under
  exploration it is nearly constant, so its gradient says little about how far a robot
  is from satisfying a limit.
* ``magnitude``: the positive parts of g, each divided by its limit's scale
  (``SCALES``: 0.1 rad/s for the speed limits, 2 rad for the joint limits, ...), summed:
  a joint rate of 0.15 rad/s costs 0.5, one of 0.3 costs 2.

Written here because SB3 has no constrained RL and the safe-RL libraries (OmniSafe,
safety-gymnasium) bring their own environments loop and pins.

May import: numpy, stable-baselines3 and ``uvms_env.env.constraints``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from uvms_env.env.constraints import CONSTRAINTS

COSTS = ("count", "magnitude")
# The scale of each constraint's limit (order of CONSTRAINTS): one unit of normalized cost
# is a violation by the whole limit.
SCALES = np.array([1.0, 2.0, 0.1, 0.1, 0.5, 1.0, 1.0, 1.0])
assert len(SCALES) == len(CONSTRAINTS)


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
    """(..., 8) constraint values -> (...) summed normalized positive parts."""
    return (np.maximum(np.asarray(g, dtype=np.float64), 0.0) / SCALES).sum(-1)


class CostPenalty(VecEnvWrapper):
    """Subtracts ``multiplier * cost`` from each robot sub-environment's reward and keeps
    each ended episode's cost; ``infos[i]["constraint_cost"]`` is the step's cost. Wraps
    ``uvms_env.vector.sb3.VectorVecEnv`` or ``baselines.rl.vec_env.ParallelVecEnv``
    directly (it reads their constraint values)."""

    def __init__(self, venv: VecEnv, settings: CostSettings) -> None:
        super().__init__(venv)
        self.settings = settings
        self.multiplier = float(settings.multiplier)
        self._episode = np.zeros(self.num_envs)
        self._finished: list[float] = []

    def reset(self) -> np.ndarray:
        self._episode[:] = 0.0
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, reward, done, infos = self.venv.step_wait()
        cost = self._costs(infos)
        self._episode += cost
        for i, c in enumerate(cost.tolist()):
            infos[i]["constraint_cost"] = c
        if done.any():
            ended = np.flatnonzero(done)
            self._finished.extend(self._episode[ended].tolist())
            self._episode[ended] = 0.0
        return obs, (reward - self.multiplier * cost).astype(np.float32), done, infos

    def _costs(self, infos: list[dict[str, Any]]) -> np.ndarray:
        if self.settings.kind == "count":
            return np.array([float(info["cost"]) for info in infos])
        batched = getattr(self.venv, "last_infos", None)
        if batched:  # the vector env: (K, N, 8) arrays, robots in sub-env order
            return magnitude_cost(batched["constraint_values"]).reshape(-1)
        g = [[info["constraint_values"][c] for c in CONSTRAINTS] for info in infos]
        return magnitude_cost(np.array(g))

    def update_multiplier(self) -> float | None:
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


class MultiplierCallback(BaseCallback):
    """After each rollout: the dual step, logged as ``lagrangian/*``."""

    def __init__(self, penalty: CostPenalty) -> None:
        super().__init__()
        self.penalty = penalty

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        mean = self.penalty.update_multiplier()
        if mean is not None:
            self.logger.record("lagrangian/episode_cost", mean)
        self.logger.record("lagrangian/multiplier", self.penalty.multiplier)
