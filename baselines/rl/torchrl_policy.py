"""A TorchRL run's actor as a per-agent policy (``--policy torchrl:RUN``), in plain torch.

The trainer (``baselines.rl.torchrl_ppo``) saves its actor here as ``actor.pt``; the
evaluator loads it without TorchRL or the trainer: the deterministic action is tanh of
the Gaussian's mean (TanhNormal's deterministic sample), with the priors the run trained
with applied as ``SB3Policy`` does (``baselines.rl.policy.run_priors``).

May import: numpy, torch, ``baselines.rl.policy`` and ``uvms_env``.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from baselines.rl.policy import RobotInputs, run_comm, run_priors
from uvms_env.policy import AgentSpec

ACTOR_FILE = "actor.pt"
CLIP_OBSERVATION = 10.0  # VecNormalize's clip_obs and clip_reward


class RunningNorm(nn.Module):
    """Running mean and variance of the last dimension (buffers, saved with the module):
    ``forward`` standardizes and clips at ``clip``. Updated in place, so the TorchRL loss's
    view of the buffers stays the module's."""

    def __init__(self, size: int, clip: float = CLIP_OBSERVATION, eps: float = 1e-8) -> None:
        super().__init__()
        self.clip, self.eps = clip, eps
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(1e-4))  # VecNormalize's prior count

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold the rows of ``x`` (..., size) in (Chan et al.'s parallel combination)."""
        x = x.reshape(-1, self.mean.shape[0]).to(self.mean.dtype)
        n = torch.tensor(float(x.shape[0]), device=x.device)
        mean, var = x.mean(0), x.var(0, unbiased=False)
        total = self.count + n
        delta = mean - self.mean
        m2 = self.var * self.count + var * n + delta**2 * self.count * n / total
        self.mean.add_(delta * n / total)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = (x - self.mean) / torch.sqrt(self.var + self.eps)
        return z.clamp(-self.clip, self.clip)


def mlp(size_in: int, hidden: list[int], size_out: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(size_in, width), nn.Tanh()]
        size_in = width
    layers.append(nn.Linear(size_in, size_out))
    return nn.Sequential(*layers)


class ActorNet(nn.Module):
    """One robot's observation (..., D) -> the TanhNormal's loc and scale (..., 8); the
    spread is a learned state-independent log std (SB3's Gaussian policy)."""

    def __init__(
        self,
        observation_size: int,
        hidden: list[int],
        log_std_init: float,
        normalize: bool,
        action_size: int = 8,  # more with an acoustic channel: the send flag, the message
    ) -> None:
        super().__init__()
        self.norm = RunningNorm(observation_size) if normalize else nn.Identity()
        self.body = mlp(observation_size, hidden, action_size)
        self.log_std = nn.Parameter(torch.full((action_size,), float(log_std_init)))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.body(self.norm(obs))
        return loc, self.log_std.exp().expand_as(loc)


def resolve_actor(path: str | None) -> Path:
    """The ``actor.pt`` of ``torchrl:PATH`` (a run folder or the file)."""
    if not path:
        raise ValueError("torchrl:PATH needs a run folder of --engine torchrl")
    file = Path(path)
    if file.is_dir():
        file = file / ACTOR_FILE
    if not file.is_file():
        raise ValueError(f"no TorchRL actor at {path} (expected {ACTOR_FILE})")
    return file


def save_actor(net: ActorNet, settings: dict[str, Any], path: Path) -> None:
    """The actor's weights and what rebuilds it, on the host."""
    state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    torch.save({"settings": settings, "state_dict": state}, path)


def load_actor(path: Path) -> ActorNet:
    data = torch.load(path, map_location="cpu", weights_only=True)
    s = data["settings"]
    net = ActorNet(
        s["observation_size"],
        s["hidden"],
        0.0,
        s["normalize_observation"],
        s.get("action_size", 8),  # actors saved before the channel: 8
    )
    net.load_state_dict(data["state_dict"])
    return net.eval()


def _load_cached(path: Path) -> ActorNet:
    """Cached until the file changes (a later run may write the same folder)."""
    st = path.stat()
    return _load_stamped(str(path.resolve()), (st.st_mtime_ns, st.st_size))


@lru_cache(maxsize=8)
def _load_stamped(path: str, stamp: tuple[int, int]) -> ActorNet:
    del stamp  # part of the cache key only
    torch.set_num_threads(1)  # one episode per process; two threads collapse when shared
    return load_actor(Path(path))


class TorchRLPolicy:
    """The shared actor acting for one robot: deterministic (tanh of the Gaussian's mean,
    TanhNormal's deterministic sample), with the priors the run trained with."""

    def __init__(self, spec: AgentSpec, path: str | None) -> None:
        file = resolve_actor(path)
        self.spec = spec
        self.net = _load_cached(file)
        self.priors = run_priors(file.parent)
        self.comm = run_comm(file.parent)
        self.reads_messages = self.comm is not None  # it sees the inbox, it may send
        self._io = RobotInputs(self.priors, spec, self.comm)
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        self._io.reset()

    def executed(self, action: np.ndarray) -> None:
        self._io.executed(action)

    def act(self, obs: np.ndarray) -> np.ndarray:
        raw, x = self._io.inputs(obs)
        with torch.no_grad():
            loc, _ = self.net(torch.as_tensor(np.asarray(x, np.float32)))
        return self._io.action(raw, np.clip(torch.tanh(loc).numpy(), -1.0, 1.0))


def factory(path: str | None):
    """``torchrl:PATH`` for ``baselines.policies``: fails before the episode starts."""
    resolve_actor(path)
    return lambda spec: TorchRLPolicy(spec, path)
