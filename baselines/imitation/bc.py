"""Behaviour cloning: regress the expert's normalized actions from observations (MSE)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from baselines.imitation.network import MLPPolicyNet


def fit(
    obs: np.ndarray,
    act: np.ndarray,
    epochs: int = 50,
    batch_size: int = 256,
    lr: float = 1e-3,
    hidden: tuple[int, ...] = (256, 256),
    seed: int = 0,
    net: MLPPolicyNet | None = None,
    log_path: Path | None = None,
    progress: bool = True,
) -> tuple[MLPPolicyNet, list[float]]:
    """Train (or continue training ``net``) and return it with the per-epoch losses."""
    if obs.ndim != 2 or act.ndim != 2 or len(obs) != len(act):
        raise ValueError(f"obs (M, D) and act (M, A) must match, got {obs.shape} and {act.shape}")
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    if net is None:
        net = MLPPolicyNet(obs.shape[1], act.shape[1], hidden)
    net.set_normalization(obs)
    net.train()
    x = torch.as_tensor(obs, dtype=torch.float32)
    y = torch.as_tensor(np.clip(act, -1, 1), dtype=torch.float32)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    losses = []
    for _ in tqdm(range(epochs), desc="bc", disable=not progress, unit="epoch"):
        perm = torch.randperm(len(x), generator=gen)
        total = 0.0
        for k in range(0, len(x), batch_size):
            idx = perm[k : k + batch_size]
            loss = torch.nn.functional.mse_loss(net(x[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        losses.append(total / len(x))
    net.eval()
    if log_path is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        new = not log_path.exists()
        with open(log_path, "a", newline="") as fh:
            w = csv.writer(fh)
            if new:
                w.writerow(["epoch", "loss"])
            for e, v in enumerate(losses):
                w.writerow([e, v])
    return net, losses
