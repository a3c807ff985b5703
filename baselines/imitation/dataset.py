"""Expert demonstrations as Minari datasets: each robot's stream is one single-agent episode.

Minari has no multi-agent support, so an episode of N robots becomes N episodes (its
observations, the expert's actions, the shared reward, terminations, and per-step
solver statistics in ``infos``). Datasets live under ``root`` (``MINARI_DATASETS_PATH``)
with ids ``uvms/NAME-v0``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

NAMESPACE = "uvms"


@dataclass
class AgentStream:
    """One robot's episode: observations (T+1, D), actions (T, 8), rewards (T,), ..."""

    observations: list[np.ndarray]
    actions: list[np.ndarray]
    rewards: list[float]
    terminations: list[bool]
    truncations: list[bool]
    solve_ms: list[float]
    seed: int

    @staticmethod
    def start(obs: np.ndarray, seed: int) -> AgentStream:
        return AgentStream([np.asarray(obs, np.float32)], [], [], [], [], [], seed)


def _dataset_id(name: str) -> str:
    return f"{NAMESPACE}/{name}-v0"


def _use_root(root: Path) -> None:
    root.mkdir(parents=True, exist_ok=True)
    os.environ["MINARI_DATASETS_PATH"] = str(root.resolve())


def write_dataset(streams: list[AgentStream], root: Path, name: str, obs_space, act_space) -> str:
    """Write the streams as a Minari dataset (replacing one of the same name)."""
    import minari
    from minari.data_collector import EpisodeBuffer

    _use_root(root)
    dataset_id = _dataset_id(name)
    if dataset_id in minari.list_local_datasets():
        minari.delete_dataset(dataset_id)
    buffers = [
        EpisodeBuffer(
            id=k,
            seed=s.seed,
            observations=np.stack(s.observations).astype(np.float32),
            actions=np.stack(s.actions).astype(np.float32),
            rewards=list(map(float, s.rewards)),
            terminations=list(map(bool, s.terminations)),
            truncations=list(map(bool, s.truncations)),
            infos={"solve_ms": np.asarray([np.nan, *s.solve_ms], dtype=np.float64)},
        )
        for k, s in enumerate(streams)
    ]
    minari.create_dataset_from_buffers(
        dataset_id,
        buffers,
        observation_space=obs_space,
        action_space=act_space,
        algorithm_name="distributed NMPC expert",
        description="Per-robot streams of the UVMS cooperative transport testbed",
    )
    return dataset_id


def read_dataset(root: Path, name: str) -> tuple[np.ndarray, np.ndarray, list]:
    """(observations (M, D), actions (M, 8), episodes) over all steps with an action."""
    import minari

    _use_root(root)
    data = minari.load_dataset(_dataset_id(name))
    episodes = list(data.iterate_episodes())
    obs = np.concatenate([ep.observations[:-1] for ep in episodes]).astype(np.float32)
    act = np.concatenate([ep.actions for ep in episodes]).astype(np.float32)
    return obs, act, episodes


def split_path(path: Path) -> tuple[Path, str]:
    """``data/NAME`` -> (root ``data``, name ``NAME``)."""
    path = Path(path)
    if not path.name or "/" in path.name:
        raise ValueError(f"dataset path must end in a name, got {path}")
    return path.parent, path.name
