"""Expert-initialized PPO: the SB3 PPO actor starts as a behaviour clone of the expert
(``--init-actor dagger:pretrained``, ``dagger:PATH`` or ``bc:PATH``).

The clones on ``features`` or ``memory`` (``baselines.networks.mlp``) compute
a = clip(a_ss + f(z), -1, 1), z = clip((x - m) / s_x, -10, 10), f a tanh MLP, x the 84
(100) features of the robot's own observation (and memory). PPO with
``action_mode=residual``, ``observation_mode`` the clone's and no joint hold computes
a = clip(a_ss + s clip(mu(z'), -1, 1), -1, 1), z' the VecNormalize'd x, mu its actor's
mean. So the clone's weights carry over: the actor's hidden layers are the clone's
(same widths, tanh), its output layer the clone's divided by the residual scale s, and
VecNormalize starts from the clone's input statistics (clip 10) with a large count
(``STATS_COUNT``) so that training moves them only slowly. The two agree exactly where
|f(z)| <= s; with s = 1 (``residual_scale=1``) that is wherever the clone's residual
stays within the saturation. The critic starts untrained.

May import: numpy, torch, stable-baselines3, ``baselines.networks`` (the clone's network) and
``baselines.loaders.clone_policy`` (inside ``load_clone``: where a named clone's ``policy.pt`` is).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.running_mean_std import RunningMeanStd

from baselines.networks.features import FEEDFORWARD, INPUT_CLIP
from baselines.networks.mlp import MLPPolicyNet

SOURCES = ("dagger", "bc")
# VecNormalize's count for the clone's statistics: a few hundred thousand robot-steps of
# training shift them by under a few percent.
STATS_COUNT = 1e7
# The actor's starting log std with an initialized actor (an SB3 policy_kwargs default):
# std 0.05 of the residual, exploration that keeps the clone's behaviour.
INIT_LOG_STD = float(np.log(0.05))


def load_clone(source: str) -> MLPPolicyNet:
    """The clone of ``dagger:pretrained`` / ``bc:PATH`` (its ``policy.pt``)."""
    from baselines.loaders.clone_policy import ClonedPolicy

    method, _, arg = source.partition(":")
    if method not in SOURCES:
        raise ValueError(f"--init-actor must be one of {SOURCES} with :pretrained or :PATH")
    net = MLPPolicyNet.load(ClonedPolicy.locate(method, arg or None))
    if net.features not in FEEDFORWARD or not net.residual:
        raise ValueError(
            f"--init-actor needs a clone on the 'features' or 'memory' inputs (a residual "
            f"around a_ss), {source} uses {net.features!r}"
        )
    return net


def check_priors(priors: Any, net: MLPPolicyNet) -> None:
    """The environment options a clone's actor carries over to (module docstring): the
    residual action and the clone's own inputs as the observation mode."""
    if priors.action_mode != "residual" or priors.observation_mode != net.features:
        raise ValueError(
            "--init-actor needs --env-option action_mode=residual "
            f"--env-option observation_mode={net.features} (the clone's inputs)"
        )
    if priors.holds:
        raise ValueError("--init-actor needs no joint hold (hold_stiffness = hold_damping = 0)")


def policy_kwargs(net: MLPPolicyNet, chosen: dict[str, Any]) -> dict[str, Any]:
    """``chosen`` policy kwargs with the clone's actor widths and tanh (a net_arch of the
    user's must match them), and the initial log std unless chosen."""
    import torch

    hidden = list(net.hidden)
    arch = chosen.get("net_arch")
    if arch is None:
        arch = {"pi": hidden, "vf": [64, 64]}
    pi = arch.get("pi") if isinstance(arch, dict) else arch
    if list(pi) != hidden:
        raise ValueError(f"--init-actor: the actor's net_arch {pi} must be the clone's {hidden}")
    activation = chosen.get("activation_fn", torch.nn.Tanh)
    if activation is not torch.nn.Tanh:
        raise ValueError("--init-actor: the actor must use tanh, as the clone does")
    return {**chosen, "net_arch": arch, "log_std_init": chosen.get("log_std_init", INIT_LOG_STD)}


def initialize(model: Any, venv: Any, net: MLPPolicyNet, residual_scale: float) -> None:
    """Copy the clone into ``model``'s actor and its input statistics into ``venv``
    (the ``VecNormalize``)."""
    import torch

    policy = model.policy
    hidden = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    layers = [m for m in net.body if isinstance(m, torch.nn.Linear)]
    if len(hidden) + 1 != len(layers):
        raise ValueError("the PPO actor and the clone have different depths")
    if policy.features_extractor_class.__name__ != "FlattenExtractor":
        raise ValueError("--init-actor needs SB3's default features extractor")
    with torch.no_grad():
        for mine, theirs in zip(hidden, layers[:-1], strict=True):
            if mine.weight.shape != theirs.weight.shape:
                raise ValueError(
                    f"layer {tuple(mine.weight.shape)} != {tuple(theirs.weight.shape)}"
                )
            mine.weight.copy_(theirs.weight)
            mine.bias.copy_(theirs.bias)
        out = layers[-1]
        policy.action_net.weight.copy_(out.weight / residual_scale)
        policy.action_net.bias.copy_(out.bias / residual_scale)
    mean = net.obs_mean.numpy().astype(np.float64)
    std = net.obs_std.numpy().astype(np.float64)
    if venv.obs_rms.mean.shape != mean.shape:
        raise ValueError(f"observation size {venv.obs_rms.mean.shape} != the clone's {mean.shape}")
    venv.obs_rms.mean = mean.copy()
    venv.obs_rms.var = np.maximum(std**2 - venv.epsilon, 0.0)
    venv.obs_rms.count = STATS_COUNT
    venv.clip_obs = INPUT_CLIP


def freeze_actor(policy: Any, frozen: bool) -> None:
    """Stop (or restart) the actor's updates: its layers, output and log std; the critic
    learns alone meanwhile (``--critic-warmup``: an initialized actor is not moved by
    the advantages of an untrained critic)."""
    params = [
        *policy.mlp_extractor.policy_net.parameters(),
        *policy.action_net.parameters(),
        policy.log_std,
    ]
    for p in params:
        p.requires_grad_(not frozen)
        if frozen:
            p.grad = None


class FrozenStatistics(RunningMeanStd):
    """Running statistics that no longer move (``--obs-stats``): the actor keeps the
    input mapping it was cloned with while VecNormalize would otherwise keep updating it.
    Saved (pickled) as SB3's plain ``RunningMeanStd``: a run's files load without this
    class, and a resumed run freezes them again only when its options say so."""

    def update(self, arr: np.ndarray) -> None:
        pass

    def __reduce_ex__(self, protocol: Any) -> tuple:
        return object.__new__, (RunningMeanStd,), dict(self.__dict__)


def freeze_statistics(venv: Any, frozen: bool) -> None:
    """Stop (or restart) the updates of ``venv``'s observation statistics (a VecNormalize)
    and nothing else: the reward's return statistics keep moving for the critic."""
    # the class swap keeps the object (and every reference to it) and pickles as is
    venv.obs_rms.__class__ = FrozenStatistics if frozen else RunningMeanStd
