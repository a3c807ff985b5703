"""The cloned network: an MLP on features of the robot's own observation (``features``),
with built-in input normalization, saved as one ``policy.pt``.

Outputs: on ``uvms-v1`` and ``raw`` features, tanh-bounded actions (the network can never
ask for more than the saturation). On ``features`` (which carry the steady input a_ss),
a linear residual: action = clip(a_ss + r, -1, 1), trained on the unclipped sum, so the
network learns only how the expert departs from holding the load at the navigation twist.

May import: numpy, torch and this package's ``features``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from baselines.networks.features import (
    ACT_DIM,
    FEEDFORWARD,
    INPUT_CLIP,
    canonical_features,
    check_features,
    prepare,
)

MIN_STD = 1e-3  # features (nearly) constant in the data are centred, not scaled


class MLPPolicyNet(nn.Module):
    """MLP on (already prepared) inputs; ``features`` says how observations are prepared.
    ``hidden=()`` is a linear map (on ``features``: a linear feedback around a_ss)."""

    def __init__(
        self,
        in_dim: int,
        act_dim: int = 8,
        hidden: tuple[int, ...] = (128, 128),
        features: str = "raw",
    ) -> None:
        super().__init__()
        features = canonical_features(features)
        check_features(features)
        self.register_buffer("obs_mean", torch.zeros(in_dim))
        self.register_buffer("obs_std", torch.ones(in_dim))
        layers: list[nn.Module] = []
        width = in_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        self.residual = features in FEEDFORWARD
        layers.append(nn.Linear(width, act_dim))
        if not self.residual:
            layers.append(nn.Tanh())
        self.body = nn.Sequential(*layers)
        self.hidden = tuple(hidden)
        self.features = features
        self.act_dim = act_dim

    def set_normalization(self, x: np.ndarray) -> None:
        """Mean and std of prepared inputs; (nearly) constant inputs are only centred."""
        std = x.std(axis=0)
        std = np.where(std < MIN_STD, 1.0, std)
        self.obs_mean.copy_(torch.as_tensor(x.mean(axis=0), dtype=torch.float32))
        self.obs_std.copy_(torch.as_tensor(std, dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The training output: tanh-bounded actions, or a_ss + residual (unclipped)."""
        z = torch.clamp((x - self.obs_mean) / self.obs_std, -INPUT_CLIP, INPUT_CLIP)
        out = self.body(z)
        return x[..., -ACT_DIM:] + out if self.residual else out

    def numpy_weights(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [
            (m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy())
            for m in self.body
            if isinstance(m, nn.Linear)
        ]

    def save(self, path: Path, meta: dict[str, Any] | None = None) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(
            {
                "state": self.state_dict(),
                "obs_dim": int(self.obs_mean.numel()),
                "act_dim": self.act_dim,
                "hidden": list(self.hidden),
                "features": self.features,
                "meta": meta or {},
            },
            path,
        )

    @staticmethod
    def load(path: Path) -> MLPPolicyNet:
        blob = torch.load(path, map_location="cpu", weights_only=False)
        net = MLPPolicyNet(
            blob["obs_dim"],
            blob["act_dim"],
            hidden=tuple(blob["hidden"]),
            features=blob["features"],
        )
        net.load_state_dict(blob["state"])
        net.eval()
        return net

    def predict(self, obs: np.ndarray, object_key: np.ndarray | float | None = None) -> np.ndarray:
        """Actions for a batch (or one) of raw observations, through torch (``object_key``:
        the object, for ``features``; see ``features.prepare``)."""
        with torch.no_grad():
            x = torch.as_tensor(prepare(obs, self.features, object_key))
            return torch.clamp(self(x), -1.0, 1.0).numpy()
