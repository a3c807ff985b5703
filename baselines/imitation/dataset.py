"""Expert demonstrations as Minari datasets: each robot's stream is one single-agent episode.

Minari has no multi-agent support, so an episode of N robots becomes N episodes (its
observations, the expert's actions, the shared reward, terminations, and per-step
expert statistics in ``infos``: ``solve_ms``, ``expert_iterations``, ``expert_fallbacks``,
``learner_acted`` (DAgger) and ``object_ring_radius`` (the object the robot carries, which
it knows before the task: the ring's radius, 0 for the bar); entry 0 belongs to the reset
observation). Datasets live under ``root`` (``MINARI_DATASETS_PATH``) with ids
``uvms/NAME-v0``.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
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
    iterations: list[int] = field(default_factory=list)  # expert solver iterations
    fallbacks: list[int] = field(default_factory=list)  # expert fallbacks so far
    learner_acted: list[bool] = field(default_factory=list)  # executed: learner (DAgger)
    object_ring_radius: float = float("nan")  # the carried object; 0 for the bar

    @staticmethod
    def start(obs: np.ndarray, seed: int, object_ring_radius: float = float("nan")) -> AgentStream:
        return AgentStream(
            [np.asarray(obs, np.float32)], [], [], [], [], [], seed,
            object_ring_radius=object_ring_radius,
        )  # fmt: skip


def _dataset_id(name: str) -> str:
    return f"{NAMESPACE}/{name}-v0"


def _use_root(root: Path) -> None:
    root.mkdir(parents=True, exist_ok=True)
    os.environ["MINARI_DATASETS_PATH"] = str(root.resolve())


def _infos(s: AgentStream) -> dict[str, np.ndarray]:
    """Per-step expert statistics, aligned with the observations (entry 0: the reset)."""
    t = len(s.actions)

    def col(values: list, dtype, pad) -> np.ndarray:
        values = list(values) if len(values) == t else [pad] * t
        return np.asarray([pad, *values], dtype=dtype)

    return {
        "solve_ms": col(s.solve_ms, np.float64, np.nan),
        "expert_iterations": col(s.iterations, np.int64, 0),
        "expert_fallbacks": col(s.fallbacks, np.int64, 0),
        "learner_acted": col(s.learner_acted, np.bool_, False),
        "object_ring_radius": np.full(t + 1, s.object_ring_radius, dtype=np.float64),
    }


def write_dataset(
    streams: list[AgentStream],
    root: Path,
    name: str,
    obs_space,
    act_space,
    algorithm: str = "distributed NMPC expert",
) -> str:
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
            infos=_infos(s),
        )
        for k, s in enumerate(streams)
    ]
    with warnings.catch_warnings():  # author, permalink, eval_env: not applicable here
        warnings.simplefilter("ignore", UserWarning)
        minari.create_dataset_from_buffers(
            dataset_id,
            buffers,
            observation_space=obs_space,
            action_space=act_space,
            algorithm_name=algorithm,
            description="Per-robot streams of the UVMS cooperative transport testbed",
        )
    return dataset_id


def read_many(paths: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Concatenated (observations, actions, object ring radius per sample; NaN where a
    dataset did not record it) of several ``data/NAME`` datasets, and the number of
    robot streams."""
    obs, act, ring, n = [], [], [], 0
    for p in paths:
        o, a, eps = read_dataset(*split_path(p))
        obs.append(o)
        act.append(a)
        ring += [
            np.full(len(ep.actions), ep.infos.get("object_ring_radius", [np.nan])[0]) for ep in eps
        ]
        n += len(eps)
    return np.concatenate(obs), np.concatenate(act), np.concatenate(ring), n


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
