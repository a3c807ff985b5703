"""What the cloned network sees: features of one robot's own observation, computed in
numpy for training batches and as one compiled CasADi function for decisions.

``features`` (84 numbers) and ``memory`` (100) are the environment's
``observation_mode="features"`` and ``"memory"``, by the same names everywhere; a
``memory`` network's input is the raw observation with the memory block after it (95
numbers). ``uvms-v1`` is the 76 heading-frame numbers alone; saved policies that say
``uvms-v2`` are read as ``features`` (``canonical_features``); ``raw`` feeds the
observation unchanged. What each holds and why a_ss: docs/imitation.md.

Decisions: ``CompiledInputs`` evaluates features, normalization and clipping as one
generated-C function through preallocated buffers. The numpy ``featurize`` is the
independent twin of ``featurize_sx``, and the expert's compiled a_ss that of
``steady_sx``; the tests check that they agree.

May import: numpy, casadi, ``uvms_env.dynamics`` and ``uvms_env.robot.priors``.
"""

from __future__ import annotations

import functools

import casadi as cs
import numpy as np

from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.payload import object_tag
from uvms_env.robot.priors import (
    ACT_DIM,
    BASE_FEATURES,
    FEATURES_SIZE,
    MEMORY_BLOCK,
    MEMORY_FEATURES_SIZE,
    OBS_DIM,
    featurize,
    featurize_sx,
    steady_inputs,
    steady_sx,
)

FEATURES = ("raw", "uvms-v1", "features", "memory")
FEEDFORWARD = ("features", "memory")  # feature sets whose last 8 numbers are the steady input
FEATURE_DIMS = {"uvms-v1": BASE_FEATURES, "features": FEATURES_SIZE, "memory": MEMORY_FEATURES_SIZE}
# ``memory`` reads the robot's memory block (uvms_env.robot.memory) after its raw observation
MEMORY_INPUT = OBS_DIM + MEMORY_BLOCK
INPUT_CLIP = 10.0  # normalized inputs are clipped to +-10 standard deviations
# Earlier names of a feature set -> its name (saved policies keep the name they had).
LEGACY_FEATURES = {"uvms-v2": "features"}


def canonical_features(features: str) -> str:
    """A feature set's name, earlier names (``LEGACY_FEATURES``) mapped to today's."""
    return LEGACY_FEATURES.get(features, features)


def check_features(features: str) -> None:
    if features not in FEATURES:
        raise ValueError(f"features must be one of {FEATURES}, got {features!r}")


def features_sx(o: cs.SX, features: str, object_key: float) -> cs.SX:
    """The features of ``o``: the raw observation, or (``memory``) the raw observation and
    the memory block after it."""
    check_features(features)
    if features == "raw":
        return o
    raw = o[:OBS_DIM]
    base = featurize_sx(raw)
    if features == "memory":
        return cs.vertcat(base, o[OBS_DIM:MEMORY_INPUT], steady_sx(raw, object_key))
    return cs.vertcat(base, steady_sx(raw, object_key)) if features in FEEDFORWARD else base


def inputs_sx(
    features: str, object_key: float, dim: int
) -> tuple[list[cs.SX], cs.SX, cs.SX | cs.DM, str]:
    """Symbolic inputs [obs, mean, inv_std, clip], the normalized clipped features z, the
    steady input (zeros for feature sets without it) and a tag for function names."""
    o = cs.SX.sym("obs", dim)
    x = features_sx(o, features, object_key)
    n = x.numel()
    mean, inv_std, clip = cs.SX.sym("mean", n), cs.SX.sym("inv_std", n), cs.SX.sym("clip")
    z = cs.fmin(clip, cs.fmax(-clip, (x - mean) * inv_std))
    ff = x[n - ACT_DIM :] if features in FEEDFORWARD else cs.DM.zeros(ACT_DIM)
    tag = f"{features.replace('-', '')}_{object_tag(object_key)}_{dim}"
    return [o, mean, inv_std, clip], z, ff, tag


@functools.cache
def input_function(features: str, object_key: float, dim: int = OBS_DIM) -> cs.Function:
    """Compiled (obs, mean, inv_std, clip) -> [z; 1; a_ss]: the normalized clipped
    features z, a constant 1 (the MLP's bias input, see ``policy``) and the steady input
    (zeros for feature sets without it), in one vector so a decision copies it once."""
    args, z, ff, tag = inputs_sx(features, object_key, dim)
    fn = cs.Function(f"cloned_inputs_{tag}", args, [cs.vertcat(z, 1.0, ff)], {"cse": True})
    return compile_function(fn)


def object_argument(object_key: float | None, features: str) -> float:
    """The object argument of the compiled functions: its key (``Scenario.object_key``,
    the datasets' ``object_key``; 0 when unused)."""
    if features in FEEDFORWARD and object_key is None:
        raise ValueError(f"{features} features need the object (its key, Scenario.object_key)")
    return float(object_key or 0.0)


def input_dim(features: str, n_features: int) -> int:
    """The observation length of the compiled functions (``raw`` takes any; ``memory``
    the raw observation and the memory block)."""
    if features == "raw":
        return n_features
    return MEMORY_INPUT if features == "memory" else OBS_DIM


class CompiledInputs:
    """``__call__(obs)`` through a compiled function of (obs, mean, inv_std, clip): by
    default ``[z; 1; a_ss]`` (``input_function``); ``fn``: another function of the same
    inputs and then ``extra`` ones, e.g. a network's whole decision and its weights
    (``mlp_decision.decision_function``). Returns a float64 view of the output buffer,
    overwritten by the next call."""

    def __init__(
        self,
        features: str,
        mean: np.ndarray,
        inv_std: np.ndarray,
        object_key: float | None = None,
        clip: float = INPUT_CLIP,
        fn: cs.Function | None = None,
        extra: tuple[np.ndarray, ...] = (),
    ) -> None:
        dim = input_dim(features, len(mean))
        if fn is None:
            fn = input_function(features, object_argument(object_key, features), dim)
        self._call = BufferCall(fn)
        self._obs = np.zeros(dim)
        self._consts = (
            np.ascontiguousarray(mean, dtype=np.float64),
            np.ascontiguousarray(inv_std, dtype=np.float64),
            np.array([clip], dtype=np.float64),
            *(np.ascontiguousarray(a, dtype=np.float64) for a in extra),
        )
        self._out = self._call(self._obs, *self._consts)[0][0]  # binds every buffer once

    @property
    def whole(self) -> tuple[cs.Function, tuple[np.ndarray, ...]]:
        """The compiled function and its constant inputs after the observation (mean,
        inv_std, clip and the ``extra`` ones): what a batch of robots maps
        (``baselines.loaders.policy_batch``)."""
        return self._call.fn, self._consts

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if obs.shape != self._obs.shape:
            raise ValueError(f"observation must have shape {self._obs.shape}, got {obs.shape}")
        self._obs[:] = obs  # one copy, with the float64 conversion
        self._call.again()
        return self._out


def prepare(
    obs: np.ndarray, features: str, object_key: np.ndarray | float | None = None
) -> np.ndarray:
    """(M, 79) observations (``memory``: (M, 95), the memory block after each) -> (M, F)
    float32 features; ``object_key`` per sample (or one value) for the feature sets that
    need the object."""
    check_features(features)
    obs = np.asarray(obs)
    if features == "raw":
        return obs.astype(np.float32)
    memory = None
    if features == "memory":
        if obs.shape[-1] != MEMORY_INPUT:
            raise ValueError(
                f"memory features need the raw observation and the memory block "
                f"({MEMORY_INPUT} numbers), got {obs.shape}"
            )
        obs, memory = obs[..., :OBS_DIM], obs[..., OBS_DIM:]
    base = featurize(obs)
    if features not in FEEDFORWARD:
        return base
    if object_key is None:
        raise ValueError(f"{features} features need the object (its key, Scenario.object_key)")
    single = obs.ndim == 1
    o2 = np.atleast_2d(obs)  # steady_inputs converts it chunk by chunk
    rings = np.broadcast_to(np.asarray(object_key, dtype=np.float64), (len(o2),))
    if np.isnan(rings).any():
        raise ValueError(
            f"{features} features need the object of every sample; "
            f"{int(np.isnan(rings).sum())} samples come from data that did not record it "
            "(no object_key in their infos): collect them again"
        )
    steady = np.zeros((len(o2), ACT_DIM), dtype=np.float32)
    for ring in np.unique(rings):
        rows = np.flatnonzero(rings == ring)
        steady[rows] = steady_inputs(o2[rows], float(ring))
    parts = [np.atleast_2d(base), steady]
    if memory is not None:
        parts.insert(1, np.atleast_2d(memory).astype(np.float32))
    out = np.concatenate(parts, axis=1)
    return out[0] if single else out
