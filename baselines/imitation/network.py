"""The cloned policy: an MLP with built-in observation normalization and tanh-bounded
actions (so it can never ask for more than the saturation), saved as one file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from uvms_env.policy import AgentSpec


class MLPPolicyNet(nn.Module):
    def __init__(
        self, obs_dim: int, act_dim: int = 8, hidden: tuple[int, ...] = (256, 256)
    ) -> None:
        super().__init__()
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))
        layers: list[nn.Module] = []
        width = obs_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        layers += [nn.Linear(width, act_dim), nn.Tanh()]
        self.body = nn.Sequential(*layers)
        self.hidden = hidden

    def set_normalization(self, obs: np.ndarray) -> None:
        self.obs_mean.copy_(torch.as_tensor(obs.mean(axis=0), dtype=torch.float32))
        self.obs_std.copy_(torch.as_tensor(obs.std(axis=0) + 1e-6, dtype=torch.float32))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.body((obs - self.obs_mean) / self.obs_std)

    def save(self, path: Path, meta: dict[str, Any] | None = None) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(
            {
                "state": self.state_dict(),
                "obs_dim": int(self.obs_mean.numel()),
                "hidden": list(self.hidden),
                "meta": meta or {},
            },
            path,
        )

    @staticmethod
    def load(path: Path) -> MLPPolicyNet:
        blob = torch.load(path, map_location="cpu", weights_only=False)
        net = MLPPolicyNet(blob["obs_dim"], hidden=tuple(blob["hidden"]))
        net.load_state_dict(blob["state"])
        net.eval()
        return net


class ClonedPolicy:
    """A saved ``policy.pt`` as a per-agent policy (the same network for every robot)."""

    def __init__(self, spec: AgentSpec, path: Path) -> None:
        torch.set_num_threads(1)
        self.spec = spec
        self.net = MLPPolicyNet.load(path)
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32)).unsqueeze(0)
        return self.net(x)[0].numpy()
