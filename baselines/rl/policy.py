"""A trained SB3 model as a per-agent policy (the shared parameters act for each robot).

A saved run folder holds ``model.zip`` and ``vecnormalize.pkl``; the policy normalizes
its own observation with the saved statistics and acts deterministically.
"""

from __future__ import annotations

import pickle
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.policy import AgentSpec

ALGOS = ("ppo", "sac")
PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "pretrained"


def resolve_run(algo: str, path: str | None) -> Path:
    """A run folder: an explicit path, or ``pretrained`` for the committed model."""
    if path in (None, "", "pretrained"):
        folder = PRETRAINED_DIR / algo
    else:
        folder = Path(path)
    if folder.is_file() and folder.suffix == ".zip":
        folder = folder.parent
    if not (folder / "model.zip").exists():
        raise ValueError(f"no {algo} model at {folder} (expected model.zip and vecnormalize.pkl)")
    return folder


def _load(algo: str, folder: str) -> tuple[Any, Any]:
    """The model and observation statistics, cached until the files change (a training
    run re-saves its evaluation snapshot into the same folder)."""
    stamps = tuple(
        (p.stat().st_mtime_ns, p.stat().st_size) if p.exists() else None
        for p in (Path(folder) / "model.zip", Path(folder) / "vecnormalize.pkl")
    )
    return _load_cached(algo, str(Path(folder).resolve()), stamps)


@lru_cache(maxsize=8)
def _load_cached(algo: str, folder: str, stamps: tuple) -> tuple[Any, Any]:
    del stamps  # part of the cache key only
    import torch
    from stable_baselines3 import PPO, SAC

    torch.set_num_threads(1)  # 2-thread torch collapses when anything else runs here
    model = {"ppo": PPO, "sac": SAC}[algo].load(Path(folder) / "model.zip", device="cpu")
    norm_path = Path(folder) / "vecnormalize.pkl"
    stats = None
    if norm_path.exists():
        with open(norm_path, "rb") as fh:
            vecnorm = pickle.load(fh)
        stats = (
            vecnorm.obs_rms.mean,
            np.sqrt(vecnorm.obs_rms.var + vecnorm.epsilon),
            vecnorm.clip_obs,
        )
    return model, stats


class SB3Policy:
    def __init__(self, spec: AgentSpec, algo: str, folder: Path) -> None:
        if algo not in ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; expected one of {ALGOS}")
        self.spec = spec
        self.model, self._norm = _load(algo, str(folder))
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float32)
        if self._norm is not None:
            mean, std, clip = self._norm
            x = np.clip((x - mean) / std, -clip, clip).astype(np.float32)
        action, _ = self.model.predict(x, deterministic=True)
        return np.clip(action, -1.0, 1.0)
