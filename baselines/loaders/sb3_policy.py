"""A trained SB3 model as a per-agent policy (the shared parameters act for each robot):
``--policy ppo:RUN`` (``sac``, ``recurrent_ppo``).

A saved run folder holds ``model.zip`` and ``vecnormalize.pkl``; the policy normalizes
its own observation with the saved statistics and acts deterministically. Finding,
caching, the run's priors and the statistics: ``baselines.loaders.saved``.

May import: numpy, stable-baselines3 and sb3-contrib (inside functions),
``baselines.loaders.saved``, ``baselines.registry``, ``baselines.networks.ppo_decision`` and
``uvms_env``.
"""

from __future__ import annotations

import pickle
from collections.abc import Hashable
from pathlib import Path
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy, ObservationStats, load_once, run_record
from baselines.registry import LIBRARIES
from uvms_env.policy import AgentSpec, PolicyFactory

ALGOS = LIBRARIES["sb3"].algos
NORMALIZER = "vecnormalize.pkl"  # VecNormalize's statistics beside model.zip


def algorithm_class(algo: str) -> Any:
    """The SB3 (or sb3-contrib) class of ``algo``."""
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[algo]


def load_model(saved: Path, algo: str) -> tuple[Any, ObservationStats | None]:
    """The model and the observation statistics beside it (None without them)."""
    model = algorithm_class(algo).load(saved, device="cpu")
    norm_path = saved.parent / NORMALIZER
    if not norm_path.exists():
        return model, None
    with open(norm_path, "rb") as fh:
        vecnorm = pickle.load(fh)
    std = np.sqrt(vecnorm.obs_rms.var + vecnorm.epsilon)
    return model, ObservationStats(vecnorm.obs_rms.mean, std, vecnorm.clip_obs)


class SB3Policy(LoadedPolicy):
    """``act(obs)``: the run's deterministic action for one robot's raw observation, as
    the normalized input. ``compiled`` (default): the whole decision as one compiled call
    (``baselines.networks.ppo_decision``) where the model allows it, else SB3's ``predict``;
    ``self.compiled`` says which. A recurrent model (``recurrent_ppo``) also keeps its
    LSTM state, cleared by ``reset``."""

    SAVED = "model.zip"
    KIND = "SB3 model"

    def __init__(self, spec: AgentSpec, algo: str, path: Path, compiled: bool = True) -> None:
        """``path``: the run folder (or its model.zip)."""
        if algo not in ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; expected one of {ALGOS}")
        saved = self.find(path)
        sources = (saved, saved.parent / NORMALIZER)
        self.model, obs_stats = load_once(load_model, saved, sources, algo)
        super().__init__(spec, *run_record(saved), obs_stats)
        self._recurrent = algo == "recurrent_ppo"
        self._state: Any = None
        self._start = True
        # MAPPO: the actor reads only the first local_dim numbers; the critic's global
        # state, which a robot does not have, is padded with zeros.
        local = getattr(self.model.policy, "local_dim", None)
        full = self.model.observation_space.shape[0]
        self._pad = np.zeros(full - local, np.float32) if local is not None else None
        self._decision = None
        if compiled and algo == "ppo" and self.comm is None:
            from baselines.networks.ppo_decision import compiled_actor

            ring = spec.object_key
            self._decision = compiled_actor(self.model, self.priors, ring, obs_stats, local)
        self.compiled = self._decision is not None

    @classmethod
    def accepts(cls, path: Path) -> bool:
        # the statistics sit beside model.zip under a fixed name: a checkpoint's zip has
        # its own (``baselines.rl.sb3_trainer.find_resume``)
        return path.is_file() and path.name == cls.SAVED

    @classmethod
    def factory(cls, name: str, arg: str | None) -> PolicyFactory:
        saved = cls.locate(name, arg)
        return lambda spec: cls(spec, name, saved)

    def reset(self) -> None:
        super().reset()
        self._state, self._start = None, True

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self._decision is None:
            return super().act(obs)
        obs = np.asarray(obs)  # the priors and the statistics are inside the decision
        block = self.inputs.block(obs)
        full = obs if block is None else np.concatenate([obs, block])
        return self.inputs.sent(self._decision(full).astype(np.float32))

    def batch_key(self) -> Hashable | None:
        return None if self._recurrent else self.stateless_key(self.model)

    def whole_decision(self) -> tuple[Any, tuple[np.ndarray, ...]] | None:
        return None if self._decision is None else self._decision.whole

    def decide_many(self, x: np.ndarray) -> np.ndarray:
        # (a recurrent model never batches: ``batch_key`` is None)
        if self._pad is not None:
            x = np.concatenate([x, np.broadcast_to(self._pad, (len(x), len(self._pad)))], 1)
        return self.model.predict(self.normalize(x), deterministic=True)[0]

    def decide(self, x: np.ndarray) -> np.ndarray:
        if self._pad is not None:
            x = np.concatenate([x, self._pad])
        x = self.normalize(x)
        if not self._recurrent:
            return self.model.predict(x, deterministic=True)[0]
        action, self._state = self.model.predict(
            x, state=self._state, episode_start=np.array([self._start]), deterministic=True
        )
        self._start = False
        return action
