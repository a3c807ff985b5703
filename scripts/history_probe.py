"""How much of the expert's action the current observation explains, and how much history.

    python scripts/history_probe.py --data data/r2c [--data ...] [--epochs 30]

Fits the same MLP (128-128 tanh, a residual on the expert's steady input a_ss, the
``features`` inputs, per-component inverse-variance weights) on one demonstration
dataset four times, with the inputs

* ``current``: the features of the current observation (what every clone reads);
* ``+ previous observation``: also the previous observation's features;
* ``+ previous action``: also the expert's previous action;
* ``+ both``;

and prints each fit's weighted MSE on the training data and on held-out episodes (every
fifth episode: the datasets hold two robot streams per episode, ``random`` N = 2); a large
gap between the two says the fit is short of data.
Why: a gap between ``current`` and the history inputs measures how much of the expert's
decision comes from its memory (warm start, input-step bound, estimators), which no policy
of the current observation can reproduce. Use clean demonstrations (``collect`` without
``--noise``): the previous action is then the one the expert applied.

An analysis script, not part of the installed packages.
May import: numpy, torch and ``baselines.imitation``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from baselines.imitation.bc import loss_weights, train_epochs
from baselines.imitation.dataset import object_key_of, read_dataset, split_path
from baselines.networks.features import prepare
from baselines.networks.mlp import MLPPolicyNet

ACT = 8
VARIANTS = ("current", "+ previous observation", "+ previous action", "+ both")


def history_inputs(
    data: Path | list[Path],
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Inputs per variant (a_ss last: the network's residual base), labels, and the
    held-out mask (by episode) of one or more ``collect`` datasets."""
    episodes = []
    for path in [data] if isinstance(data, Path) else data:
        episodes += read_dataset(*split_path(path))[2]
    parts: dict[str, list[np.ndarray]] = {v: [] for v in VARIANTS}
    labels, held = [], []
    for j, ep in enumerate(episodes):
        f = prepare(ep.observations[:-1], "features", object_key_of(ep))
        act = np.clip(ep.actions, -1, 1).astype(np.float32)
        prev_f = np.vstack([f[:1], f[:-1]])[:, :-ACT]  # the first step repeats itself
        prev_a = np.vstack([np.clip(f[:1, -ACT:], -1, 1), act[:-1]])  # a_ss before any
        parts["current"].append(f)
        parts["+ previous observation"].append(np.hstack([prev_f, f]))
        parts["+ previous action"].append(np.hstack([prev_a, f]))
        parts["+ both"].append(np.hstack([prev_f, prev_a, f]))
        labels.append(act)
        held.append(np.full(len(act), (j // 2) % 5 == 0))  # two streams (robots) per episode
    inputs = {v: np.concatenate(p).astype(np.float32) for v, p in parts.items()}
    return inputs, np.concatenate(labels), np.concatenate(held)


def fit_losses(x: np.ndarray, y: np.ndarray, held: np.ndarray, epochs: int) -> tuple[float, float]:
    """(training, held-out) weighted MSE of the MLP fitted on the rows not held out."""
    torch.manual_seed(0)
    net = MLPPolicyNet(x.shape[1], ACT, (128, 128), features="features")
    net.set_normalization(x[~held])
    weight = torch.as_tensor(loss_weights(y, "std"))
    xt, yt = torch.as_tensor(x[~held]), torch.as_tensor(y[~held])
    gen = torch.Generator().manual_seed(0)
    for _ in train_epochs(net, xt, yt, weight, epochs, 256, 1e-3, "cosine", gen):
        pass
    net.eval()
    with torch.no_grad():
        losses = []
        for rows in (~held, held):
            err = net(torch.as_tensor(x[rows])) - torch.as_tensor(y[rows])
            losses.append(float(((err**2) * weight).mean()))
    return losses[0], losses[1]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python scripts/history_probe.py", allow_abbrev=False)
    ap.add_argument(
        "--data", type=Path, action="append", required=True, help="a collect dataset, data/NAME"
    )
    ap.add_argument("--epochs", type=int, default=30)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    inputs, labels, held = history_inputs(args.data)
    print(f"{len(labels)} samples, {int(held.sum())} held out")
    for name, x in inputs.items():
        train, test = fit_losses(x, labels, held, args.epochs)
        print(f"{name:>24}: {x.shape[1]} inputs, weighted MSE {train:.2e} fit, {test:.2e} held out")


if __name__ == "__main__":
    main()
