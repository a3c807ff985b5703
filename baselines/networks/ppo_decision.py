"""A trained SB3 PPO actor's whole deterministic decision as one compiled function.

The decision is one generated-C call (instead of the model's ``predict``, torch and
numpy): the run's priors (features and a_ss, ``uvms_env.robot.priors`` in CasADi),
the saved observation normalization, the actor's layers (the cloned networks' loop nest,
``baselines.networks.mlp_decision.dense_c``) and the action's way to the input (clip to
[-1, 1]; in residual mode clip(a_ss + h + s a, -1, 1) with the joint hold h).

Supported: PPO with an MLP actor of tanh layers (SB3's default), the central-critic
policy's local actor included. Anything else (SAC's ReLU actor, other activations)
returns None and the policy keeps ``predict``. The hidden tanh is the clones' rational
approximation and the layers run in float32, so actions agree with torch's to ~1e-6.

May import: numpy, casadi, torch and stable-baselines3 (inside ``ppo_layers``, on the
model), ``uvms_env`` and this package's ``features`` and ``mlp_decision`` (the clones'
compiled-network code).
"""

from __future__ import annotations

from typing import Any

import casadi as cs
import numpy as np

from baselines.networks.features import FEEDFORWARD, CompiledInputs, input_dim, inputs_sx
from baselines.networks.mlp_decision import (
    architecture_tag,
    layer_widths,
    network_graph,
    pack_layers,
)
from uvms_env.dynamics.compiled import compile_function
from uvms_env.robot.priors import ACT_DIM, OBS_DIM, Priors, steady_sx

NO_CLIP = 1e30  # a model saved without observation normalization


def ppo_layers(model: Any) -> list[np.ndarray] | None:
    """The deterministic actor of an SB3 PPO model as ``dense_c`` layers ((n + 1, m)
    weights with the bias as the last row, tanh between layers), or None where it is not
    an MLP of tanh layers behind a flattening feature extractor."""
    import torch
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy = getattr(model, "policy", None)
    extractor = getattr(policy, "mlp_extractor", None)
    if extractor is None or not isinstance(policy.features_extractor, FlattenExtractor):
        return None
    if getattr(policy, "squash_output", False):
        return None
    modules = [*extractor.policy_net, policy.action_net]
    linear = [m for m in modules if isinstance(m, torch.nn.Linear)]
    # exactly Linear, Tanh, Linear, Tanh, ..., Linear (the action head)
    expected = [torch.nn.Linear, torch.nn.Tanh] * (len(linear) - 1) + [torch.nn.Linear]
    if [type(m) for m in modules] != expected or linear[-1].out_features != ACT_DIM:
        return None
    return [
        np.vstack([m.weight.detach().cpu().numpy().T, m.bias.detach().cpu().numpy()[None]])
        for m in linear
    ]


_CACHE: dict[tuple, cs.Function | None] = {}


def actor_function(
    priors: Priors, object_key: float, widths: tuple[int, ...]
) -> cs.Function | None:
    """Compiled (obs, mean, inv_std, clip, weights) -> normalized input of a robot whose
    raw observation is ``obs``, for an actor of ``widths`` (``weights``: its
    ``pack_layers``; one library per priors, object and widths, every model of that
    architecture its user), or None where nothing is compiled (no C compiler)."""
    key = (priors, float(object_key), widths)
    if key not in _CACHE:  # an evaluation builds a policy per robot and episode
        _CACHE[key] = _build(priors, object_key, widths)
    return _CACHE[key]


def _build(priors: Priors, object_key: float, widths: tuple[int, ...]) -> cs.Function | None:
    features = priors.observation_mode  # the feature sets share the modes' names
    args, z, ff, tag = inputs_sx(features, object_key, input_dim(features, OBS_DIM))
    if z.numel() != widths[0]:
        raise ValueError(f"the actor reads {widths[0]} numbers, the run's priors give {z.numel()}")
    if priors.action_mode == "torque":
        steady = cs.DM.zeros(ACT_DIM)
    elif priors.action_mode == "setpoint":  # the holding a_ss, not the features' own
        steady = steady_sx(priors.steady_source(args[0]), object_key)
    else:
        steady = ff if features in FEEDFORWARD else steady_sx(args[0], object_key)
    name = f"ppo_actor_{tag}_{architecture_tag(widths)}_{priors.action_mode}"
    weights, out = network_graph(name, z, widths)
    act = priors.command_sx(args[0], out, steady)
    fn = cs.Function(name, [*args, weights], [act], {"cse": True})
    compiled = compile_function(fn)
    return None if compiled is fn else compiled


def compiled_actor(
    model: Any,
    priors: Priors,
    object_key: float,
    norm: tuple[np.ndarray, np.ndarray, float] | None,
    local_dim: int | None,
) -> CompiledInputs | None:
    """``__call__(raw_obs) -> input`` (float64 view, overwritten by the next call) for an
    SB3 PPO model, or None where it cannot be compiled (see the module docstring); in the
    memory mode ``raw_obs`` is followed by the robot's memory block.
    ``norm``: the saved (mean, std, clip); ``local_dim``: the actor's share of a central
    critic's observation (the first numbers)."""
    layers = ppo_layers(model)
    if layers is None:
        return None
    width = len(layers[0]) - 1
    # the actor must read the whole observation (or, with a central critic, its local part)
    if width != (local_dim if local_dim is not None else model.observation_space.shape[0]):
        return None
    if norm is None:
        mean, inv_std, clip = np.zeros(width), np.ones(width), NO_CLIP
    else:
        mean, std, clip = norm
        mean, inv_std = np.asarray(mean)[:width], 1.0 / np.asarray(std)[:width]
    fn = actor_function(priors, object_key, layer_widths(layers))
    if fn is None:
        return None
    features = priors.observation_mode  # the feature sets share the modes' names
    return CompiledInputs(
        features, mean, inv_std, object_key, clip, fn=fn, extra=(pack_layers(layers),)
    )
