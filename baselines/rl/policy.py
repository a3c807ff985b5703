"""A trained SB3 model as a per-agent policy (the shared parameters act for each robot).

A saved run folder holds ``model.zip`` and ``vecnormalize.pkl``; the policy normalizes
its own observation with the saved statistics and acts deterministically. A model trained
with the environment's ``action_mode`` / ``observation_mode`` options (recorded in the
run's ``config.json``) applies the same ``uvms_env.env.priors.Priors`` itself, so it acts
in any environment through the plain interface: it sees the raw observation and returns
the normalized input.
"""

from __future__ import annotations

import json
import pickle
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.env.channel import ChannelSettings, channel_settings
from uvms_env.env.memory import RobotMemory
from uvms_env.env.observation import OBSERVATION_SIZE
from uvms_env.env.options import ENV_OPTIONS, priors_of
from uvms_env.env.priors import Priors
from uvms_env.policy import AgentSpec

ALGOS = ("ppo", "sac", "recurrent_ppo")
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


def algorithm_class(algo: str) -> Any:
    """The SB3 (or sb3-contrib) class of ``algo``."""
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[algo]


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

    torch.set_num_threads(1)  # one episode per process: threads shared with others stall
    model = algorithm_class(algo).load(Path(folder) / "model.zip", device="cpu")
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


def run_priors(folder: Path) -> Priors:
    """The action and observation modes a run trained with (plain without a config)."""
    config = Path(folder) / "config.json"
    if not config.exists():
        return Priors()
    return priors_from_options(json.loads(config.read_text()).get("overrides", {}))


def comm_from_options(options: dict[str, Any]) -> ChannelSettings | None:
    """The acoustic channel among a run's recorded environment options (None: off)."""
    return channel_settings(options.get("comm"))


def run_comm(folder: Path) -> ChannelSettings | None:
    """The acoustic channel a run trained with (None: the silent team)."""
    config = Path(folder) / "config.json"
    if not config.exists():
        return None
    return comm_from_options(json.loads(config.read_text()).get("overrides", {}))


class RobotInputs:
    """What every trained policy's adapter does around its network, written once: the
    robot's raw observation to the network's input (the run's priors, the robot's memory
    in the memory mode, the inbox under a channel) and the network's numbers back to the
    env action (the priors' command of the first 8, then the send flag and message as they
    are). ``inputs`` then ``action`` once per decision; ``reset`` at each episode;
    ``executed`` when another controller (a safety filter) sent something else."""

    def __init__(
        self, priors: Priors, spec: AgentSpec, comm: ChannelSettings | None = None
    ) -> None:
        self.priors, self.comm = priors, comm
        self.ring = spec.object_ring_radius
        self.memory = RobotMemory(spec.period, self.ring) if priors.remembers else None

    def reset(self) -> None:
        if self.memory is not None:
            self.memory.reset()

    def executed(self, action: np.ndarray) -> None:
        if self.memory is not None:
            self.memory.executed(np.asarray(action)[:NU])

    def block(self, obs: np.ndarray) -> np.ndarray | None:
        """The memory block of this decision (None without a memory); call once per
        decision, before ``action``."""
        if self.memory is None:
            return None
        return self.memory.observe(np.asarray(obs, np.float32)[:OBSERVATION_SIZE])

    def inputs(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(raw observation, network input) of one robot's env observation."""
        return policy_input(self.priors, obs, self.ring, self.comm, self.block(obs))

    def action(self, raw: np.ndarray, chosen: np.ndarray) -> np.ndarray:
        """The env action of the network's ``chosen`` numbers (and the memory's command)."""
        return self.sent(policy_action(self.priors, raw, chosen, self.ring, self.comm))

    def sent(self, action: np.ndarray) -> np.ndarray:
        """``action`` as the robot sends it; the memory notes its inputs."""
        if self.memory is not None:
            self.memory.issued(action[:NU])
        return action


def policy_input(
    priors: Priors,
    obs: np.ndarray,
    ring: float,
    comm: ChannelSettings | None,
    memory: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(raw observation, network input) of one robot's env observation: the priors'
    observation of the raw part (with the robot's ``memory`` block in the memory mode),
    then, under a channel, the inbox as the env appends it."""
    obs = np.asarray(obs, dtype=np.float32)
    if comm is None:
        return obs, priors.observe(obs, ring, memory=memory)
    raw = obs[:OBSERVATION_SIZE]
    x = np.asarray(priors.observe(raw, ring, memory=memory), np.float32)
    return raw, np.concatenate([x, obs[OBSERVATION_SIZE:]])


def policy_action(
    priors: Priors, raw: np.ndarray, chosen: np.ndarray, ring: float, comm: ChannelSettings | None
) -> np.ndarray:
    """The env action of a network's ``chosen`` numbers: the priors' command of the first 8,
    then, under a channel, the send flag and the message as they are."""
    if comm is None:
        return priors.command(raw, chosen, ring).astype(np.float32)
    control = priors.command(raw, chosen[:NU], ring)
    return np.concatenate([control, chosen[NU:]]).astype(np.float32)


def priors_from_options(options: dict[str, Any]) -> Priors:
    """The priors among a run's recorded environment options (checked again)."""
    mine = ("action_mode", "observation_mode", "residual_scale", "hold_stiffness", "hold_damping")
    return priors_of({k: ENV_OPTIONS[k].check(k, v) for k, v in options.items() if k in mine})


class SB3Policy:
    """``act(obs)``: the run's deterministic action for one robot's raw observation, as
    the normalized input. ``compiled`` (default): the whole decision as one compiled call
    (``baselines.rl.actor``) where the model allows it, else SB3's ``predict``;
    ``self.compiled`` says which. The priors, the memory and the channel: ``RobotInputs``;
    a recurrent model (``recurrent_ppo``) also keeps its LSTM state, cleared by ``reset``."""

    def __init__(self, spec: AgentSpec, algo: str, folder: Path, compiled: bool = True) -> None:
        if algo not in ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; expected one of {ALGOS}")
        self.spec = spec
        self.model, self._norm = _load(algo, str(folder))
        self.priors = run_priors(folder)
        self.comm = run_comm(folder)
        self.reads_messages = self.comm is not None  # it sees the inbox, it may send
        self._io = RobotInputs(self.priors, spec, self.comm)
        self._recurrent = algo == "recurrent_ppo"
        self._state: Any = None
        self._start = True
        # MAPPO: the actor reads only the first local_dim numbers; the critic's global
        # state, which a robot does not have, is padded with zeros.
        local = getattr(self.model.policy, "local_dim", None)
        full = self.model.observation_space.shape[0]
        self._pad = np.zeros(full - local, np.float32) if local is not None else None
        self._decide = None
        if compiled and algo == "ppo" and self.comm is None:
            from baselines.rl.actor import compiled_actor

            ring = spec.object_ring_radius
            self._decide = compiled_actor(self.model, self.priors, ring, self._norm, local)
        self.compiled = self._decide is not None
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        self._io.reset()
        self._state, self._start = None, True

    def executed(self, action: np.ndarray) -> None:
        self._io.executed(action)

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if self._decide is not None:  # the priors are inside the compiled decision
            block = self._io.block(obs)
            full = obs if block is None else np.concatenate([obs, block])
            return self._io.sent(self._decide(full).astype(np.float32))
        raw, x = self._io.inputs(obs)
        if self._pad is not None:
            x = np.concatenate([x, self._pad])
        if self._norm is not None:
            mean, std, clip = self._norm
            x = np.clip((x - mean) / std, -clip, clip).astype(np.float32)
        if self._recurrent:
            action, self._state = self.model.predict(
                x, state=self._state, episode_start=np.array([self._start]), deterministic=True
            )
            self._start = False
        else:
            action, _ = self.model.predict(x, deterministic=True)
        return self._io.action(raw, np.clip(action, -1.0, 1.0))
