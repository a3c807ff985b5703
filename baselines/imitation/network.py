"""The cloned policy: an MLP on invariant features of the robot's own observation, with
built-in input normalization and tanh-bounded actions (it can never ask for more than the
saturation), saved as one ``policy.pt``.

Features (``features="uvms-v1"``, 76 numbers from the 79-number observation): the
dynamics and the expert are invariant to horizontal translation and to a rotation about
the vertical, so absolute north/east positions and absolute headings are replaced by
differences expressed in the robot's own heading frame (the vehicle's yaw psi): the
active waypoint and the goal relative to the own object estimate, the attitude errors
(wrapped), the navigation twist, the object twist, the vehicle's position relative to
the object and the three nearest obstacles (absent ones zeroed, distances clamped to 5 m).
Depths, roll, pitch, joint angles, the body-frame twist, load share and grasp are kept
as they are. ``time_fraction`` is dropped: it depends on ``max_cycles``, which the
expert ignores. ``features="raw"`` feeds the observation unchanged (any dimension).

At decision time the network runs in numpy (~15-30 us per decision instead of ~60-100 us
through torch's dispatcher for this size); ``ClonedPolicy`` checks against torch on load.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from uvms_env.policy import AgentSpec

FEATURES = ("raw", "uvms-v1")
OBS_DIM = 79
FEATURE_DIM = 76
OBSTACLE_RANGE = 5.0  # m; obstacle offsets beyond this are scaled down to it
INPUT_CLIP = 10.0  # normalized inputs are clipped to +-10 standard deviations
MIN_STD = 1e-3  # features (nearly) constant in the data are centred, not scaled


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def featurize(obs: np.ndarray) -> np.ndarray:
    """(..., 79) observations -> (..., 76) float32 invariant features (see module doc)."""
    o = np.asarray(obs, dtype=np.float64)
    if o.shape[-1] != OBS_DIM:
        raise ValueError(f"uvms-v1 features need {OBS_DIM}-number observations, got {o.shape}")
    psi = o[..., 5]
    c, s = np.cos(psi), np.sin(psi)

    def yaw_frame(v: np.ndarray) -> np.ndarray:  # (..., 3) NED -> heading frame
        return np.stack(
            [c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], -1
        )

    pose = o[..., 20:26]
    wp, goal = o[..., 32:38], o[..., 38:44]
    obst = o[..., 50:65].reshape(*o.shape[:-1], 3, 5)
    present = (obst[..., 3] > 0).astype(np.float64)
    dxy = obst[..., :2]
    dist = np.linalg.norm(dxy, axis=-1, keepdims=True)
    dxy = dxy * np.minimum(1.0, OBSTACLE_RANGE / np.maximum(dist, 1e-9))
    cc, ss = c[..., None], s[..., None]
    ob_body = np.stack(
        [cc * dxy[..., 0] + ss * dxy[..., 1], -ss * dxy[..., 0] + cc * dxy[..., 1]], -1
    )
    obstacles = np.concatenate(
        [ob_body * present[..., None], obst[..., 2:5] * present[..., None]], -1
    ).reshape(*o.shape[:-1], 15)
    parts = [
        o[..., 2:5],  # vehicle depth, roll, pitch
        o[..., 6:10],  # joint angles
        o[..., 10:20],  # body twist and joint rates
        pose[..., 2:5],  # object depth, roll, pitch
        _wrap(pose[..., 5:6] - psi[..., None]),  # object yaw relative to the vehicle's
        yaw_frame(o[..., 26:29]),
        yaw_frame(o[..., 29:32]),
        yaw_frame(wp[..., :3] - pose[..., :3]),
        _wrap(wp[..., 3:] - pose[..., 3:]),
        yaw_frame(goal[..., :3] - pose[..., :3]),
        _wrap(goal[..., 3:] - pose[..., 3:]),
        yaw_frame(o[..., 44:47]),
        o[..., 47:50],
        obstacles,
        yaw_frame(o[..., 0:3] - pose[..., :3]),
        o[..., 65:78],  # load share, grasp offset, grasp rotation
    ]
    return np.concatenate(parts, -1).astype(np.float32)


def _wrap1(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def featurize_one(obs: np.ndarray) -> np.ndarray:
    """``featurize`` of one observation in plain Python floats (~5x faster than the
    vectorized version on one row; the tests check they agree)."""
    o = np.asarray(obs, dtype=np.float64).tolist()
    if len(o) != OBS_DIM:
        raise ValueError(f"uvms-v1 features need {OBS_DIM}-number observations, got {len(o)}")
    psi = o[5]
    c, s = math.cos(psi), math.sin(psi)
    px, py, pz = o[20], o[21], o[22]
    f = o[2:5] + o[6:20] + o[22:25] + [_wrap1(o[25] - psi)]
    for i in (26, 29):
        f += [c * o[i] + s * o[i + 1], -s * o[i] + c * o[i + 1], o[i + 2]]
    for i in (32, 38):
        dx, dy = o[i] - px, o[i + 1] - py
        f += [c * dx + s * dy, -s * dx + c * dy, o[i + 2] - pz]
        f += [_wrap1(o[i + 3 + k] - o[23 + k]) for k in range(3)]
    f += [c * o[44] + s * o[45], -s * o[44] + c * o[45], o[46], *o[47:50]]
    obst: list[float] = []
    for i in (50, 55, 60):
        if o[i + 3] > 0:
            dx, dy = o[i], o[i + 1]
            scale = min(1.0, OBSTACLE_RANGE / max(math.hypot(dx, dy), 1e-9))
            dx, dy = dx * scale, dy * scale
            obst += [c * dx + s * dy, -s * dx + c * dy]
            rest = o[i + 2 : i + 5]
        else:
            obst += [0.0, 0.0]
            rest = [0.0, 0.0, 0.0]
        obst += rest
    f += obst
    dx, dy = o[0] - px, o[1] - py
    f += [c * dx + s * dy, -s * dx + c * dy, o[2] - pz]
    f += o[65:78]
    return np.asarray(f, dtype=np.float32)


def prepare(obs: np.ndarray, features: str) -> np.ndarray:
    if features == "raw":
        return np.asarray(obs, dtype=np.float32)
    if features == "uvms-v1":
        return featurize_one(obs) if np.ndim(obs) == 1 else featurize(obs)
    raise ValueError(f"features must be one of {FEATURES}, got {features!r}")


class MLPPolicyNet(nn.Module):
    """MLP on (already prepared) inputs; ``features`` says how observations are prepared."""

    def __init__(
        self,
        in_dim: int,
        act_dim: int = 8,
        hidden: tuple[int, ...] = (256, 256),
        features: str = "raw",
    ) -> None:
        super().__init__()
        if features not in FEATURES:
            raise ValueError(f"features must be one of {FEATURES}, got {features!r}")
        self.register_buffer("obs_mean", torch.zeros(in_dim))
        self.register_buffer("obs_std", torch.ones(in_dim))
        layers: list[nn.Module] = []
        width = in_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        layers += [nn.Linear(width, act_dim), nn.Tanh()]
        self.body = nn.Sequential(*layers)
        self.hidden = tuple(hidden)
        self.features = features

    def set_normalization(self, x: np.ndarray) -> None:
        """Mean and std of prepared inputs; (nearly) constant inputs are only centred."""
        std = x.std(axis=0)
        std = np.where(std < MIN_STD, 1.0, std)
        self.obs_mean.copy_(torch.as_tensor(x.mean(axis=0), dtype=torch.float32))
        self.obs_std.copy_(torch.as_tensor(std, dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = torch.clamp((x - self.obs_mean) / self.obs_std, -INPUT_CLIP, INPUT_CLIP)
        return self.body(z)

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
                "act_dim": int(self.body[-2].out_features),
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
            blob.get("act_dim", 8),
            hidden=tuple(blob["hidden"]),
            features=blob.get("features", "raw"),
        )
        net.load_state_dict(blob["state"])
        net.eval()
        return net

    def predict(self, obs: np.ndarray) -> np.ndarray:
        """Actions for a batch (or one) of raw observations, through torch."""
        with torch.no_grad():
            x = torch.as_tensor(prepare(obs, self.features))
            return self(x).numpy()


def load_meta(path: Path) -> dict[str, Any]:
    return torch.load(path, map_location="cpu", weights_only=False).get("meta", {})


class ClonedPolicy:
    """A saved ``policy.pt`` as a per-agent policy (the same network for every robot;
    stateless, so ``reset`` does nothing). Inference in numpy float32."""

    def __init__(self, spec: AgentSpec | None, path: Path) -> None:
        torch.set_num_threads(1)
        self.spec = spec
        self.net = MLPPolicyNet.load(path)
        self.features = self.net.features
        self._mean = self.net.obs_mean.numpy().copy()
        self._inv_std = (1.0 / self.net.obs_std).numpy().copy()
        self._layers = self.net.numpy_weights()
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        h = prepare(obs, self.features)
        h = np.clip((h - self._mean) * self._inv_std, -INPUT_CLIP, INPUT_CLIP)
        for w, b in self._layers:
            h = np.tanh(h @ w + b)
        return np.clip(h, -1.0, 1.0)
