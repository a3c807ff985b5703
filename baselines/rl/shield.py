"""Shielded training: every robot's proposal passes through the expert's safety filter
(``nmpc_expert.SafetyFilter``) before it reaches the environment, as ``+filter`` does
at evaluation, and the reward carries a penalty on the filter's correction.

    shield = Shield(vector_env, penalty=1.0)   # installs itself as the env's command filter
    venv = ShieldPenalty(VectorVecEnv(vector_env), shield)   # SB3: reward -= W |a_safe - a_prop|^2

``Shield`` keeps one filter per (env copy, robot), fed only that robot's raw observation,
and filters the normalized command the environment made of the learner's action; the
learner keeps what it proposed. The QP builders of all robots run in one lane-parallel
call (``nmpc_expert.filter_batch``; ``batched=False`` or no C++ compiler: each filter's
``act``). Reference: docs/rl.md, docs/safety-filter.md.

May import: numpy, stable-baselines3 (``ShieldPenalty``), ``nmpc_expert`` and ``uvms_env``.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

from uvms_env.policy import AgentSpec

# The per-iteration summary ``Shield.summary`` returns (``shield.csv`` in a run folder).
SHIELD_COLUMNS = (
    "robot_steps",
    "filter_penalty_mean",
    "correction_sq_mean",
    "intervention_rate",
    "fallbacks",  # since the start of the run
    "filter_ms_per_robot_step",
)
SHIELD_FILE = "shield.csv"


class Proposal:
    """The inner policy of a training filter: the command set for this step."""

    def __init__(self) -> None:
        self.command = np.zeros(8)
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        del obs
        return self.command


class Shield:
    """The safety filters of a ``VectorEnv``'s K N robots (module docstring). Installs
    itself as ``vector_env.command_filter``. After each step: ``proposal`` and ``safe``
    (K, N, 8) commands, ``correction_sq`` (K, N) |a_safe - a_prop|^2, ``penalty`` (K, N)
    its weighted value. ``filter_options``: ``SafetyFilter``'s keyword arguments."""

    def __init__(
        self, vector_env: Any, penalty: float = 1.0, batched: bool = True, **filter_options: Any
    ) -> None:
        if not (np.isfinite(penalty) and penalty >= 0):
            raise ValueError(f"the filter penalty must be a finite number >= 0, got {penalty!r}")
        if getattr(vector_env, "backend", "cpu") != "cpu":
            raise ValueError("the training shield runs on the VectorEnv's CPU backend")
        self.env = vector_env
        self.weight = float(penalty)
        self.options = filter_options
        k, n = vector_env.num_envs, vector_env.n
        self.shape = (k, n)
        self.proposals = [[Proposal() for _ in range(n)] for _ in range(k)]
        self.filters: list[list[Any]] = [[None] * n for _ in range(k)]
        self._scenario: list[Any] = [None] * k
        self.proposal = np.zeros((k, n, 8))
        self.safe = np.zeros((k, n, 8))
        self.correction_sq = np.zeros((k, n))
        self.penalty = np.zeros((k, n))
        self._totals = np.zeros(5)  # robot-steps, penalty, correction^2, interventions, s
        self._fallbacks = 0
        self._batch = None
        if batched:
            from nmpc_expert.filter_batch import BatchedFilterStep

            self._batch = BatchedFilterStep()
        vector_env.command_filter = self

    def _start(self, k: int) -> None:
        """Copy ``k`` starts an episode: its robots' filters for its scenario, reset."""
        from nmpc_expert import SafetyFilter  # the expert is optional at import time

        scenario = self.env.scenarios[k]
        if scenario is not self._scenario[k]:
            for i in range(self.shape[1]):
                old = self.filters[k][i]
                if old is not None:
                    self._fallbacks += old.fallbacks
                spec = AgentSpec.from_scenario(scenario, i)
                self.filters[k][i] = SafetyFilter(spec, self.proposals[k][i], **self.options)
            self._scenario[k] = scenario
        for f in self.filters[k]:
            self._fallbacks += f.fallbacks
            f.reset()

    def __call__(self, raw: np.ndarray, commands: np.ndarray, first: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        k_count, n = self.shape
        first = np.asarray(first)
        np.copyto(self.proposal, commands)
        for k in range(k_count):
            if first[k] or self.filters[k][0] is None:
                self._start(k)
            for i in range(n):
                self.proposals[k][i].command = self.proposal[k, i]
        filters = [f for row in self.filters for f in row]
        observations = list(raw.reshape(k_count * n, -1))
        if self._batch is not None:
            try:
                self.safe[:] = self._batch(filters, observations).reshape(k_count, n, -1)
            except RuntimeError as err:  # no C++ compiler: one robot after another
                warnings.warn(f"no batched safety filters ({err}): one by one", stacklevel=2)
                self._batch = None
        if self._batch is None:
            for j, (f, o) in enumerate(zip(filters, observations, strict=True)):
                self.safe.reshape(k_count * n, -1)[j] = f.act(o)
        interventions = sum(bool(f.stats.get("intervened", False)) for f in filters)
        np.sum((self.safe - self.proposal) ** 2, axis=-1, out=self.correction_sq)
        np.multiply(self.weight, self.correction_sq, out=self.penalty)
        self._totals += (
            k_count * n,
            self.penalty.sum(),
            self.correction_sq.sum(),
            interventions,
            time.perf_counter() - start,
        )
        return self.safe.copy()

    def summary(self, robot_steps: int) -> dict[str, Any]:
        """The means since the last summary (one row of ``SHIELD_COLUMNS``); restarts them."""
        steps, penalty, correction, interventions, seconds = self._totals
        fallbacks = self._fallbacks + sum(f.fallbacks for row in self.filters for f in row if f)
        per = max(steps, 1.0)
        row = {
            "robot_steps": int(robot_steps),
            "filter_penalty_mean": round(penalty / per, 6),
            "correction_sq_mean": round(correction / per, 6),
            "intervention_rate": round(interventions / per, 4),
            "fallbacks": int(fallbacks),
            "filter_ms_per_robot_step": round(1e3 * seconds / per, 4),
        }
        self._totals[:] = 0.0
        return row


class ShieldPenalty(VecEnvWrapper):
    """SB3 ``VecEnvWrapper`` over a ``VectorVecEnv`` stack: each robot sub-environment's
    reward minus its ``Shield.penalty`` this step (also ``infos[i]["filter_penalty"]``)."""

    def __init__(self, venv: Any, shield: Shield) -> None:
        super().__init__(venv)
        # the wrappers' attribute look-up reaches down to the VectorVecEnv's
        if getattr(venv, "vector_env", None) is not shield.env:
            raise ValueError("ShieldPenalty needs the VecEnv stack over the shield's VectorEnv")
        self.shield = shield

    def reset(self) -> np.ndarray:
        return self.venv.reset()

    def step_wait(self) -> Any:
        obs, reward, done, infos = self.venv.step_wait()
        penalty = self.shield.penalty.reshape(-1)
        for i, p in enumerate(penalty.tolist()):
            infos[i]["filter_penalty"] = p
        return obs, (reward - penalty).astype(np.float32), done, infos
