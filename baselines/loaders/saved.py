"""Saved networks as per-robot policies: the one base every adapter derives from (SB3,
RLlib, BenchMARL, the clones), the one rule that finds a saved policy, the one cache of
loaded networks (``load_once``) and the run record they read (``run_record``).

* ``LoadedPolicy.locate(name, arg)``, for ``--policy NAME:ARG``: ARG ``pretrained`` (or
  none) is the committed model ``baselines/pretrained/NAME``; a bare word naming a
  committed variant ``baselines/pretrained/NAME_ARG`` is that model (``student:expert``,
  the student taught by the distributed expert); a folder that holds the
  loader's ``SAVED`` item (``model.zip``, ``actor.pt``, ``policy.pt``, ``checkpoint/``) is
  a run folder; anything else must be such an item itself (a file of its kind, an RLlib
  checkpoint folder).
* ``LoadedPolicy``: the robot's side of every adapter, written once: its priors around the
  network (``RobotInputs``: features and a_ss in, the priors' command out, the robot's
  memory, the inbox under a channel), the observation statistics the network was trained
  with, ``reset`` / ``executed`` / ``stats``. An adapter loads its network and says how it
  decides (``decide``).

May import: numpy, torch (inside the cache: every saved network is torch's) and
``uvms_env``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Hashable, Iterable
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.env.options import ENV_OPTIONS, priors_of
from uvms_env.policy import AgentSpec, PolicyFactory
from uvms_env.robot.channel import ChannelSettings, channel_settings
from uvms_env.robot.memory import RobotMemory
from uvms_env.robot.observation import OBSERVATION_SIZE
from uvms_env.robot.priors import Priors

PRETRAINED = Path(__file__).resolve().parents[1] / "pretrained"  # the committed models
CONFIG_FILE = "config.json"  # a training run's record (``baselines.runs``)
# the environment options a trained policy applies itself: the fields of ``Priors``
PRIOR_OPTIONS = tuple(f.name for f in dataclasses.fields(Priors))
CACHED_NETWORKS = 16


# -- the cache ------------------------------------------------------------------------------
def file_stamp(paths: Iterable[Path]) -> tuple[tuple[Any, ...], ...]:
    """(path, modification time, size) of each file, a folder's files recursively; a
    missing file as (path, None)."""
    stamp: list[tuple[Any, ...]] = []
    for path in map(Path, paths):
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        for file in files:
            if file.exists():
                st = file.stat()
                stamp.append((str(file), st.st_mtime_ns, st.st_size))
            else:
                stamp.append((str(file), None))
    return tuple(stamp)


def load_once(
    load: Callable[..., Any], saved: Path, sources: Iterable[Path] = (), *args: Any
) -> Any:
    """``load(saved, *args)``, loaded once per saved item, ``args`` and stamp of the files
    it reads (``sources``, default ``saved`` itself)."""
    stamp = file_stamp(tuple(sources) or (saved,))
    return _load_stamped(load, str(Path(saved).resolve()), stamp, args)


@lru_cache(maxsize=CACHED_NETWORKS)
def _load_stamped(load: Callable[..., Any], path: str, stamp: tuple, args: tuple) -> Any:
    del stamp  # part of the key only
    import torch

    torch.set_num_threads(1)  # one episode per process: threads shared with others stall
    return load(Path(path), *args)


# -- the run record -------------------------------------------------------------------------
def read_config(folder: Path) -> dict[str, Any]:
    """A run's config.json ({} when it has none)."""
    path = Path(folder) / CONFIG_FILE
    return json.loads(path.read_text()) if path.exists() else {}


def priors_from_options(options: dict[str, Any]) -> Priors:
    """The priors among a run's recorded environment options (checked again)."""
    mine = {k: v for k, v in options.items() if k in PRIOR_OPTIONS}
    return priors_of({k: ENV_OPTIONS[k].check(k, v) for k, v in mine.items()})


def options_record(options: dict[str, Any]) -> tuple[Priors, ChannelSettings | None]:
    """The priors and the acoustic channel (None: off) among a run's recorded environment
    options: what a saved policy applies around its network."""
    return priors_from_options(options), channel_settings(options.get("comm"))


def nearest_config(saved: Path) -> dict[str, Any]:
    """The config.json of the run that saved ``saved``: the nearest in the saved item's
    folder or the two above it ({} without one)."""
    configs = map(read_config, list(Path(saved).resolve().parents)[:3])
    return next(filter(None, configs), {})


def run_record(saved: Path) -> tuple[Priors, ChannelSettings | None]:
    """The priors and the channel of the run that saved ``saved`` (``nearest_config``);
    plain and silent without one."""
    config = nearest_config(saved)
    return options_record({**config.get("env_options", {}), **config.get("overrides", {})})


# -- the robot's side of a network ----------------------------------------------------------
class ObservationStats(NamedTuple):
    """The input normalization a network was trained with: clip((x - mean) / std, +-clip)."""

    mean: np.ndarray
    std: np.ndarray
    clip: float

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.clip((x - self.mean) / self.std, -self.clip, self.clip).astype(np.float32)


class RobotInputs:
    """What an adapter does around its network: the robot's raw observation to the
    network's input (the run's priors, the robot's memory in the memory mode, the inbox
    under a channel) and the network's numbers back to the env action (the priors' command
    of the first 8, then the send flag and message as they are). ``inputs`` then ``action``
    once per decision (or ``block`` then ``sent`` around a decision that applies the priors
    itself); ``reset`` at each episode; ``executed`` when another controller (a safety
    filter) sent something else. ``spec`` may be None for plain priors."""

    def __init__(
        self, priors: Priors, spec: AgentSpec | None, comm: ChannelSettings | None = None
    ) -> None:
        if spec is None and not priors.plain:
            raise ValueError(f"{priors} need the robot's AgentSpec (its object)")
        self.priors, self.comm = priors, comm
        self.ring = spec.object_key if spec is not None else 0.0
        self.memory = None
        if priors.remembers:
            assert spec is not None
            self.memory = RobotMemory(spec.period, self.ring)

    def reset(self) -> None:
        if self.memory is not None:
            self.memory.reset()

    def executed(self, action: np.ndarray) -> None:
        if self.memory is not None:
            self.memory.executed(np.asarray(action)[:NU])

    def block(self, obs: np.ndarray) -> np.ndarray | None:
        """The memory block of this decision (None without a memory); call once per
        decision, before ``action`` / ``sent``."""
        return None if self.memory is None else self.memory.observe(obs)

    def inputs(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(raw observation, network input) of one robot's env observation: the priors'
        observation of the raw part, then, under a channel, the inbox as the env appends
        it."""
        obs = np.asarray(obs, dtype=np.float32)
        memory = self.block(obs)
        if self.comm is None:
            return obs, self.priors.observe(obs, self.ring, memory=memory)
        raw = obs[:OBSERVATION_SIZE]
        x = np.asarray(self.priors.observe(raw, self.ring, memory=memory), np.float32)
        return raw, np.concatenate([x, obs[OBSERVATION_SIZE:]])

    def action(self, raw: np.ndarray, chosen: np.ndarray) -> np.ndarray:
        """The env action of the network's ``chosen`` numbers: the priors' command of the
        first 8, then, under a channel, the send flag and the message as they are."""
        if self.comm is None:
            return self.sent(self.priors.command(raw, chosen, self.ring).astype(np.float32))
        control = self.priors.command(raw, chosen[:NU], self.ring)
        return self.sent(np.concatenate([control, chosen[NU:]]).astype(np.float32))

    def sent(self, action: np.ndarray) -> np.ndarray:
        """``action`` as the robot sends it; the memory notes its inputs."""
        if self.memory is not None:
            self.memory.issued(action[:NU])
        return action


class LoadedPolicy:
    """A saved network acting for one robot (see the module docstring). A subclass names
    what a run saves (``SAVED``, ``KIND`` for messages), loads its network through
    ``load_once``, calls ``__init__`` with the run's priors, channel and observation
    statistics, and implements ``decide``: the network's numbers for its input."""

    SAVED: ClassVar[str]
    KIND: ClassVar[str]

    def __init__(
        self,
        spec: AgentSpec | None,
        priors: Priors,
        comm: ChannelSettings | None = None,
        obs_stats: ObservationStats | None = None,
    ) -> None:
        self.spec = spec
        self.priors, self.comm, self.obs_stats = priors, comm, obs_stats
        self.reads_messages = comm is not None  # it sees the inbox, it may send
        self.inputs = RobotInputs(priors, spec, comm)
        self.stats: dict[str, Any] = {}

    # -- finding a saved policy ---------------------------------------------------------------
    @classmethod
    def accepts(cls, path: Path) -> bool:
        """``path`` is a saved item of this kind: by default a file with ``SAVED``'s suffix."""
        return path.is_file() and path.suffix == Path(cls.SAVED).suffix

    @classmethod
    def find(cls, path: Path | str) -> Path:
        """The saved item in the run folder ``path``, or ``path`` itself."""
        path = Path(path)
        for candidate in (path / cls.SAVED, path):
            if cls.accepts(candidate):
                return candidate
        raise ValueError(f"no {cls.KIND} at {path} (expected {cls.SAVED})")

    @classmethod
    def locate(cls, name: str, arg: str | None) -> Path:
        """The saved item of ``NAME:ARG`` (the module docstring's rule)."""
        if arg in (None, "", "pretrained"):
            return cls.find(PRETRAINED / name)
        variant = PRETRAINED / f"{name}_{arg}"
        if arg.isidentifier() and variant.is_dir():
            return cls.find(variant)
        return cls.find(Path(arg))

    @classmethod
    def factory(cls, name: str, arg: str | None) -> PolicyFactory:
        """``--policy NAME:ARG``: found now (an error before the episode starts), loaded
        once, one policy per robot."""
        saved = cls.locate(name, arg)
        return lambda spec: cls(spec, saved)

    # -- acting ---------------------------------------------------------------------------------
    def reset(self) -> None:
        self.inputs.reset()

    def executed(self, action: np.ndarray) -> None:
        self.inputs.executed(action)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """``x`` in the training's observation statistics (as it is without any)."""
        return x if self.obs_stats is None else self.obs_stats(x)

    def act(self, obs: np.ndarray) -> np.ndarray:
        raw, x = self.inputs.inputs(obs)
        return self.inputs.action(raw, np.clip(self.decide(x), -1.0, 1.0))

    def decide(self, x: np.ndarray) -> np.ndarray:
        """The network's deterministic numbers for its input ``x`` (the priors' observation,
        then the inbox)."""
        raise NotImplementedError

    # -- deciding for many robots at once (``baselines.loaders.policy_batch``) ---------------
    def batch_key(self) -> Hashable | None:
        """Robots whose policies have one key (not None) can decide in one call: the same
        network and statistics, priors, object and period. None (the default): this
        policy decides alone (a recurrent network's state, a channel's inbox)."""
        return None

    def stateless_key(self, network: Any) -> Hashable | None:
        """``batch_key`` of a loader whose decision keeps no state and whose ``network`` is
        the object ``load_once`` shares between its robots."""
        if self.comm is not None or self.spec is None:
            return None
        # the statistics come with the network (loaded with it, or its own)
        return (type(self), id(network), self.priors, self.inputs.ring, self.spec.period)

    def whole_decision(self) -> tuple[Any, tuple[np.ndarray, ...]] | None:
        """The compiled function of ([raw observation; memory block], constants...) that is
        this policy's whole decision, priors included, and its constants; None where the
        decision is ``decide`` between the priors."""
        return None

    def decide_many(self, x: np.ndarray) -> np.ndarray:
        """``decide`` of each row of ``x`` (robots, inputs): one call of the network where
        the loader can (the default decides row by row)."""
        return np.stack([np.asarray(self.decide(row)) for row in x])
