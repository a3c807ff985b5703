"""Behaviour cloning: regress the expert's normalized actions from observations (MSE).

Targets are clipped to [-1, 1] (the saturation: the network's tanh output cannot go
beyond it). A random ``val_fraction`` of the samples is held out to report a validation
loss; the CSV log gets one row per epoch (``stage, epoch, train_loss, val_loss``).

``loss_scale="std"`` divides each action component's error by that component's standard
deviation in the data: the arm-joint and yaw torques vary ~3x less than the surge and sway
forces, and an unweighted MSE lets their (relatively) large errors through, which then
integrate into joint drift. ``lr_schedule="cosine"`` anneals the step size to zero over
the epochs (a lower final loss at the same cost). ``margin_weight`` weighs each sample
by how near the robot is to a speed or joint limit (``margin_weights``).
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from baselines.networks.features import prepare
from baselines.networks.mlp import MLPPolicyNet

LOG_FIELDS = ["stage", "epoch", "samples", "train_loss", "val_loss"]
LOSS_SCALES = ("none", "std")
LR_SCHEDULES = ("constant", "cosine")
MIN_ACTION_STD = 0.02  # a (nearly) constant action component is not blown up


def loss_weights(act: np.ndarray, loss_scale: str) -> np.ndarray:
    """Per-component weights of the squared error (mean weight 1, so losses stay comparable
    in size with the unweighted MSE)."""
    if loss_scale == "none":
        return np.ones(act.shape[1], dtype=np.float32)
    if loss_scale == "std":
        w = 1.0 / np.maximum(np.clip(act, -1, 1).std(axis=0), MIN_ACTION_STD) ** 2
        return (w / w.mean()).astype(np.float32)
    raise ValueError(f"loss_scale must be one of {LOSS_SCALES}, got {loss_scale!r}")


def margin_weights(obs: np.ndarray, strength: float) -> np.ndarray:
    """Per-sample weights 1 + ``strength`` p^2 (mean 1 over the samples), p in [0, 1] how
    far into the outer half of its range the robot's nearest speed or joint limit is,
    from its own measured state (the first 79 numbers of each sample: the raw
    observation): p = clip(2 max_c |x_c| / limit_c - 1, 0, 1) over its joint angles, joint
    rates, vehicle linear and angular rates. Near a limit the expert's action is decided
    by the constraint rather than the task (set-valued away from it): a clone that is off
    there violates, so those samples count more (``--margin-weight``)."""
    if strength < 0:
        raise ValueError(f"margin weight must be >= 0, got {strength}")
    if strength == 0:
        return np.ones(len(obs), dtype=np.float32)
    from uvms_env.dynamics.uvms import default_model
    from uvms_env.robot.observation import OBSERVATION_STRUCTURE

    limits = default_model().params.limits
    q = obs[:, OBSERVATION_STRUCTURE["q"]]
    zeta = obs[:, OBSERVATION_STRUCTURE["zeta"]]
    ratios = np.concatenate(
        [
            np.abs(q[:, 6:]) / limits.joint_position,
            np.abs(zeta[:, 6:]) / limits.joint_speed,
            np.abs(zeta[:, :3]) / limits.vehicle_linear_speed,
            np.abs(zeta[:, 3:6]) / limits.vehicle_angular_speed,
        ],
        axis=1,
    )
    p = np.clip(2.0 * ratios.max(axis=1) - 1.0, 0.0, 1.0)
    w = 1.0 + strength * p**2
    return (w / w.mean()).astype(np.float32)


def fit(
    obs: np.ndarray,
    act: np.ndarray,
    epochs: int = 50,
    batch_size: int = 256,
    lr: float = 1e-3,
    hidden: tuple[int, ...] = (128, 128),
    seed: int = 0,
    net: MLPPolicyNet | None = None,
    features: str = "raw",
    val_fraction: float = 0.0,
    log_path: Path | None = None,
    stage: str = "bc",
    progress: bool = True,
    loss_scale: str = "none",
    lr_schedule: str = "constant",
    object_key: np.ndarray | float | None = None,
    margin_weight: float = 0.0,
) -> tuple[MLPPolicyNet, list[float]]:
    """Train a new network (or continue training ``net``, keeping its normalization) and
    return it with the per-epoch training losses (weighted as ``loss_scale`` says, and per
    sample by ``margin_weights`` with ``margin_weight`` > 0). ``object_key``: the object
    per sample, for features that need it."""
    if obs.ndim != 2 or act.ndim != 2 or len(obs) != len(act):
        raise ValueError(f"obs (M, D) and act (M, A) must match, got {obs.shape} and {act.shape}")
    if lr_schedule not in LR_SCHEDULES:
        raise ValueError(f"lr_schedule must be one of {LR_SCHEDULES}, got {lr_schedule!r}")
    weight = torch.as_tensor(loss_weights(act, loss_scale))
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    x_all = prepare(obs, net.features if net is not None else features, object_key)
    if net is None:
        net = MLPPolicyNet(x_all.shape[1], act.shape[1], hidden, features=features)
        net.set_normalization(x_all)
    gen = torch.Generator().manual_seed(seed)
    perm = torch.randperm(len(x_all), generator=gen)
    n_val = round(val_fraction * len(x_all)) if len(x_all) > 1 else 0
    val_idx, train_idx = perm[:n_val], perm[n_val:]
    x = torch.as_tensor(x_all, dtype=torch.float32)
    y = torch.as_tensor(np.clip(act, -1, 1), dtype=torch.float32)
    samples = torch.as_tensor(margin_weights(np.asarray(obs), margin_weight))[:, None]
    xv, yv, sv = x[val_idx], y[val_idx], samples[val_idx]
    x, y, samples = x[train_idx], y[train_idx], samples[train_idx]

    losses: list[float] = []
    rows = []
    bar = tqdm(total=epochs, desc=stage, disable=not progress, unit="epoch")
    steps = train_epochs(net, x, y, weight * samples, epochs, batch_size, lr, lr_schedule, gen)
    for epoch, train_loss in enumerate(steps):
        losses.append(train_loss)
        net.eval()
        val = float("nan")
        if n_val:
            with torch.no_grad():
                val = ((net(xv) - yv) ** 2 * weight * sv).mean().item()
        rows.append([stage, epoch, len(x), losses[-1], val])
        bar.update()
        bar.set_postfix(loss=f"{losses[-1]:.3g}", val=f"{val:.3g}")
    bar.close()
    net.eval()
    if log_path is not None:
        log_path = Path(log_path)
        log_path.parent.mkdir(parents=True, exist_ok=True)
        new = not log_path.exists()
        with open(log_path, "a", newline="") as fh:
            w = csv.writer(fh)
            if new:
                w.writerow(LOG_FIELDS)
            w.writerows(rows)
    return net, losses


def train_epochs(
    net: MLPPolicyNet,
    x: torch.Tensor,
    y: torch.Tensor,
    weight: torch.Tensor,
    epochs: int,
    batch_size: int,
    lr: float,
    lr_schedule: str,
    gen: torch.Generator,
) -> Iterator[float]:
    """Adam on the weighted MSE of ``net`` over (x, y), shuffled by ``gen``; yields each
    epoch's mean training loss (the network left in training mode until then). ``weight``:
    per component (A,), or per sample and component (M, A)."""
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    steps_per_epoch = max(1, -(-len(x) // batch_size))
    sched = (
        torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps_per_epoch)
        if lr_schedule == "cosine"
        else None
    )
    for _ in range(epochs):
        net.train()
        order = torch.randperm(len(x), generator=gen)
        total = 0.0
        for k in range(0, len(x), batch_size):
            idx = order[k : k + batch_size]
            w = weight[idx] if weight.ndim == 2 else weight
            loss = ((net(x[idx]) - y[idx]) ** 2 * w).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            if sched is not None:
                sched.step()
            total += loss.item() * len(idx)
        yield total / max(1, len(x))
