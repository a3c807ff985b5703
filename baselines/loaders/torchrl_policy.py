"""A TorchRL run's actor as a per-agent policy (``--policy torchrl:RUN``), in plain torch.

The evaluator loads the trainer's ``actor.pt`` without TorchRL or the trainer: the
deterministic action is tanh of the Gaussian's mean (TanhNormal's deterministic sample);
the observation statistics are the actor's own (``RunningNorm``); the run's priors:
``baselines.loaders.saved``.

May import: numpy, torch, ``baselines.loaders.saved`` and ``uvms_env``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from baselines.loaders.saved import LoadedPolicy, load_once, run_record
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


class TorchRLPolicy(LoadedPolicy):
    """The shared actor acting for one robot: deterministic (tanh of the Gaussian's mean,
    TanhNormal's deterministic sample), with the priors the run trained with."""

    SAVED = ACTOR_FILE
    KIND = "TorchRL actor"

    def __init__(self, spec: AgentSpec, path: Path) -> None:
        """``path``: the run folder (or its actor.pt)."""
        saved = self.find(path)
        self.net = load_once(load_actor, saved)
        super().__init__(spec, *run_record(saved))

    def decide(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            loc, _ = self.net(torch.as_tensor(np.asarray(x, np.float32)))
        return torch.tanh(loc).numpy()
