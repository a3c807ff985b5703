"""Expert demonstrations as Minari datasets: each robot's stream is one single-agent episode.

Minari has no multi-agent support, so an episode of N robots becomes N episodes (entry 0
of the per-step ``infos`` belongs to the reset observation). Dataset ``data/NAME`` is a
Minari root of its own (``MINARI_DATASETS_PATH`` = ``data/NAME``, id ``uvms/NAME-v0``), so
other folders next to it never reach Minari's scan of its root. What an episode holds:
docs/imitation.md.

Each dataset records the environment it came from as a Gymnasium ``EnvSpec`` of
``uvms_env/CoopTransport-v1`` with the scenario and its overrides as kwargs, so
``load(path).recover_environment()`` builds it. That is the centralized Gymnasium view
(``uvms_env.env.gym_wrapper``): robot i's observation and action are the slices
``[79 i, 79 (i + 1))`` and ``[8 i, 8 (i + 1))`` of its spaces, while the dataset's spaces
are one robot's.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

NAMESPACE = "uvms"
#: The ``infos`` key of the carried object's key (``Scenario.object_key``) ...
OBJECT_KEY = "object_key"
#: ... and its name in datasets recorded before the rename (still read: ``object_key_of``)
OLD_OBJECT_KEY = "object_ring_radius"


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
    object_key: float = float("nan")  # the carried object's key (Scenario's)
    # (T+1, 16): the robot's memory block at each observation (uvms_env.robot.memory)
    memory: list[np.ndarray] = field(default_factory=list)

    @staticmethod
    def start(obs: np.ndarray, seed: int, object_key: float = float("nan")) -> AgentStream:
        return AgentStream(
            [np.asarray(obs, np.float32)], [], [], [], [], [], seed,
            object_key=object_key,
        )  # fmt: skip


def _use_root(own: Path) -> str:
    """Dataset folder ``data/NAME`` made Minari's root (a root of its own); the id of the
    dataset in it."""
    own.mkdir(parents=True, exist_ok=True)
    os.environ["MINARI_DATASETS_PATH"] = str(own.resolve())
    return f"{NAMESPACE}/{own.name}-v0"


def env_spec(scenario: str, **kwargs: Any):
    """The Gymnasium ``EnvSpec`` of ``uvms_env/CoopTransport-v1`` built with ``scenario``
    and ``kwargs`` (scenario overrides and environment options; JSON-serializable)."""
    import gymnasium

    from uvms_env.env.registration import ENV_ID, register_gymnasium

    register_gymnasium()
    return dataclasses.replace(gymnasium.spec(ENV_ID), kwargs={"scenario": scenario, **kwargs})


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
        # the object's key (read back with object_key_of, which knows the old name too)
        OBJECT_KEY: np.full(t + 1, s.object_key, dtype=np.float64),
        **({"memory": np.stack(s.memory).astype(np.float32)} if len(s.memory) == t + 1 else {}),
    }


def write_dataset(
    streams: list[AgentStream],
    root: Path,
    name: str,
    obs_space,
    act_space,
    algorithm: str = "distributed NMPC expert",
    spec=None,
) -> str:
    """Write the streams as Minari dataset ``root/NAME`` (replacing one of the same name).
    ``spec``: the environment's ``EnvSpec`` (see ``env_spec``), for
    ``recover_environment``; None records none."""
    import minari
    from minari.data_collector import EpisodeBuffer

    own = Path(root) / name
    dataset_id = _use_root(own)
    # no minari.list_local_datasets(): it parses every folder under the root as an id
    if (own / NAMESPACE / f"{name}-v0").exists():
        shutil.rmtree(own / NAMESPACE / f"{name}-v0")
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
            env=spec,
            observation_space=obs_space,
            action_space=act_space,
            algorithm_name=algorithm,
            description="Per-robot streams of the UVMS cooperative transport testbed",
        )
    return dataset_id


def read_many(
    paths: list[Path], memory: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Concatenated (observations, actions, object key per sample; NaN where a
    dataset did not record it) of several ``data/NAME`` datasets, and the number of
    robot streams. ``memory``: each observation followed by the robot's memory block
    (``memory`` features; ValueError where a dataset did not record it)."""
    obs, act, ring, n = [], [], [], 0
    for p in paths:
        o, a, eps = read_dataset(*split_path(p))
        if memory:
            if any("memory" not in ep.infos for ep in eps):
                raise ValueError(
                    f"{p} has no memory blocks (collected before they were recorded): "
                    "collect it again for memory features"
                )
            blocks = np.concatenate([np.asarray(ep.infos["memory"])[:-1] for ep in eps])
            o = np.concatenate([o, blocks.astype(np.float32)], axis=1)
        obs.append(o)
        act.append(a)
        ring += [np.full(len(ep.actions), object_key_of(ep)) for ep in eps]
        n += len(eps)
    return np.concatenate(obs), np.concatenate(act), np.concatenate(ring), n


def object_key_of(episode: Any) -> float:
    """The carried object's key (``Scenario.object_key``) that a dataset episode recorded:
    its ``infos``' ``object_key``, or ``object_ring_radius`` in datasets recorded before
    the rename; NaN where it recorded neither."""
    for key in (OBJECT_KEY, OLD_OBJECT_KEY):
        if key in episode.infos:
            return float(np.asarray(episode.infos[key])[0])
    return float("nan")


def load(path: Path):
    """The ``minari.MinariDataset`` of dataset ``data/NAME``."""
    import minari

    root, name = split_path(path)
    return minari.load_dataset(_use_root(Path(root) / name))


def read_dataset(root: Path, name: str) -> tuple[np.ndarray, np.ndarray, list]:
    """(observations (M, D), actions (M, 8), episodes) over all steps with an action."""
    data = load(Path(root) / name)
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
