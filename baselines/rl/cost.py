"""The SB3 trainer's side of ``baselines.lagrangian``: a VecEnv wrapper that subtracts the
multiplier times each robot sub-environment's constraint cost from its reward.

May import: numpy, stable-baselines3 and ``baselines.lagrangian``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from baselines.lagrangian import CostSettings, Lagrangian, periods_left


class CostPenalty(VecEnvWrapper):
    """Subtracts ``multiplier * cost`` from each robot sub-environment's reward and keeps
    each ended episode's cost; ``infos[i]["constraint_cost"]`` is the step's cost. Wraps
    ``uvms_env.vector.sb3.VectorVecEnv`` directly (it reads its constraint values)."""

    def __init__(self, venv: VecEnv, settings: CostSettings) -> None:
        super().__init__(venv)
        self.settings = settings
        self.lagrangian = Lagrangian(settings, self.num_envs)

    @property
    def multiplier(self) -> float:
        return self.lagrangian.multiplier

    @multiplier.setter
    def multiplier(self, value: float) -> None:
        self.lagrangian.multiplier = float(value)

    def reset(self) -> np.ndarray:
        self.lagrangian.reset()
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, reward, done, infos = self.venv.step_wait()
        g = None
        if self.settings.kind == "magnitude":
            # the vector env's (K, N, C) values, robots in sub-env order
            g = self.venv.last_infos["constraint_values"]
        count = [float(info["cost"]) for info in infos]
        cost = self.lagrangian.penalize(g, count, done, [periods_left(i) for i in infos])
        for i, c in enumerate(cost.tolist()):
            infos[i]["constraint_cost"] = c
        return obs, (reward - self.multiplier * cost).astype(np.float32), done, infos

    def update_multiplier(self) -> float | None:
        """One dual step (``Lagrangian.end_rollout``)."""
        return self.lagrangian.end_rollout()


def find_layer(venv: Any, cls: type) -> Any:
    """The layer of type ``cls`` inside the VecEnv stack (below a ``ConcatVecEnv`` of
    several groups, in its first part), or None."""
    while venv is not None and not isinstance(venv, cls):
        if isinstance(venv, VecEnvWrapper):
            venv = venv.venv
        else:  # a ConcatVecEnv's first part; None at the stack's bottom
            venv = next(iter(getattr(venv, "parts", [])), None)
    return venv
