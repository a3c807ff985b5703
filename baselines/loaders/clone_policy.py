"""A saved ``policy.pt`` as a per-agent policy for the evaluator and DAgger rollouts.

One decision is one call of a compiled function, observation to action
(``baselines.networks.mlp_decision``).
Where nothing is compiled (``UVMS_ENV_NO_COMPILE``, no C compiler), or with
``compiled=False``, a network with hidden layers runs its layers in numpy float32 after
the compiled input function instead. The torch network (``MLPPolicyNet.predict``) is the
reference both are tested against. The same network serves every robot; on ``memory``
features each robot's policy keeps its own ``RobotMemory``. Finding, caching and the
memory: ``baselines.loaders.saved``.

May import: numpy, torch, ``uvms_env``, ``baselines.loaders.saved`` and ``baselines.networks``
(the network, its features and its compiled decision).
"""

from __future__ import annotations

from collections.abc import Hashable
from pathlib import Path
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy, ObservationStats, load_once
from baselines.networks.features import INPUT_CLIP, CompiledInputs, input_dim, object_argument
from baselines.networks.mlp import MLPPolicyNet
from baselines.networks.mlp_decision import decision_function
from uvms_env.policy import AgentSpec
from uvms_env.robot.observation import OBSERVATION_SIZE
from uvms_env.robot.priors import MEMORY_BLOCK, Priors


class ClonedPolicy(LoadedPolicy):
    """``act(obs)``: the network's action for one robot's observation, in [-1, 1];
    ``compiled``: the whole decision as one compiled call (the default), or the numpy
    layers (see the module docstring). The features, the statistics and a_ss are inside
    the decision: the base's priors only say whether the robot keeps its memory (the
    memory mode for ``memory`` features, else plain)."""

    SAVED = "policy.pt"
    KIND = "cloned policy"

    def __init__(self, spec: AgentSpec | None, path: Path, compiled: bool = True) -> None:
        """``path``: a folder with policy.pt, or the file."""
        self.path = self.find(path)
        self.net = load_once(MLPPolicyNet.load, self.path)
        self.features = self.net.features
        if self.features == "memory" and spec is None:
            raise ValueError("a clone on memory features needs the robot's AgentSpec")
        std = self.net.obs_std.numpy()
        stats = ObservationStats(self.net.obs_mean.numpy(), std, INPUT_CLIP)
        memory = Priors(observation_mode="memory" if self.features == "memory" else "raw")
        super().__init__(spec, memory, obs_stats=stats)
        mean, inv_std = stats.mean, 1.0 / std
        object_key = spec.object_key if spec is not None else None
        # Each layer's bias rides as the last row of its weights, against a constant 1 at
        # the end of its input (see ``input_function``).
        layers = [np.vstack([w, b[None]]) for w, b in self.net.numpy_weights()]
        self._residual = self.net.residual
        decision = None
        if compiled or len(layers) == 1:  # a linear map is CasADi expressions: runs anywhere
            decision = decision_function(
                self.features,
                object_argument(object_key, self.features),
                layers,
                self._residual,
                input_dim(self.features, len(mean)),
            )
        self.compiled = decision is not None
        fn, extra = decision if decision is not None else (None, ())
        self._network_inputs = CompiledInputs(
            self.features, mean, inv_std, object_key=object_key, fn=fn, extra=extra
        )
        if self.inputs.memory is not None:
            self._with_memory = np.zeros(OBSERVATION_SIZE + MEMORY_BLOCK, np.float32)
        if not self.compiled:
            self._numpy_layers(layers)

    def _numpy_layers(self, layers: list[np.ndarray]) -> None:
        # ~2 numpy calls per layer; the first input, [z; 1; a_ss], comes whole from the
        # compiled input function.
        layers = [w.astype(np.float32) for w in layers]
        self._hidden, self._last = layers[:-1], layers[-1]
        n_in = len(layers[0])
        self._first = np.ones(n_in + 8, dtype=np.float32)
        self._x, self._steady = self._first[:n_in], self._first[n_in:]
        self._buffers = [np.ones(len(w), dtype=np.float32) for w in layers[1:]]

    def batch_key(self) -> Hashable | None:
        # the numpy layers decide row by row: only the compiled decision batches
        return self.stateless_key(self.net) if self.compiled else None

    def whole_decision(self) -> tuple[Any, tuple[np.ndarray, ...]] | None:
        return self._network_inputs.whole if self.compiled else None

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if self.inputs.memory is None:
            return self.decide(obs)
        # one preallocated input: the decision is tens of microseconds, numpy's
        # allocations were a third of it
        if obs.shape != (OBSERVATION_SIZE,):
            raise ValueError(
                f"a memory clone acts on one raw observation ({OBSERVATION_SIZE},), got {obs.shape}"
            )
        x = self._with_memory
        x[:OBSERVATION_SIZE] = obs
        x[OBSERVATION_SIZE:] = self.inputs.block(obs)
        return self.inputs.sent(self.decide(x))

    def decide(self, obs: np.ndarray) -> np.ndarray:
        """The action of the raw observation (with the memory block on ``memory``)."""
        if self.compiled:
            return self._network_inputs(obs).astype(np.float32)
        np.copyto(self._first, self._network_inputs(obs), casting="same_kind")
        h = self._x
        for w, nxt in zip(self._hidden, self._buffers, strict=True):
            np.tanh(h @ w, out=nxt[:-1])
            h = nxt
        out = h @ self._last
        if self._residual:
            out += self._steady
            np.maximum(out, -1.0, out=out)
            return np.minimum(out, 1.0, out=out)
        return np.tanh(out, out=out)  # float32 tanh never leaves [-1, 1]
