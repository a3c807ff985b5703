"""What the cloned network sees: features of one robot's own observation, computed in
numpy for training batches and as one compiled CasADi function for decisions.

``uvms-v1`` (76 numbers from the 79-number observation): the dynamics and the expert are
invariant to horizontal translation and to a rotation about the vertical, so absolute
north/east positions and absolute headings are replaced by differences expressed in the
robot's own heading frame (the vehicle's yaw psi): the active waypoint and the goal
relative to the own object estimate, the attitude errors (wrapped), the navigation
twist, the object twist, the vehicle's position relative to the object and the three
nearest obstacles (absent ones zeroed, distances clamped to 5 m). Depths, roll, pitch,
joint angles, the body-frame twist, load share and grasp are kept as they are.
``time_fraction`` is dropped: it depends on ``max_cycles``, which the expert ignores.

``uvms-v2`` (84): ``uvms-v1`` and the steady input a_ss (8): the normalized input that
holds this robot, with its load share of the object, moving rigidly at the navigation
twist against weight, buoyancy and drag. It is the expert's own input reference (its
R-weighted cost pulls towards it), computed by the same model function
(``nmpc_expert.ocp.build_steady_input``), from the robot's own measured q and zeta, its
grasp and load share (in the observation), the navigation twist (in the observation;
its Euler-angle rates stand in for the angular velocity) and the object's nominal
parameters, which each robot knows before the task (``AgentSpec``; datasets record the
object per stream). Networks on ``uvms-v2`` learn the residual a - a_ss
(``network.MLPPolicyNet``). Why: the holding forces depend on the grasp geometry and the
load share through the arm's kinematics; a clone that must learn them from ~100
training geometries got them wrong on new ones (heave +0.12 where the expert holds with
-0.37), and the episode drifted from there. Measured on 16 held-out random N = 2
episodes, behaviour cloning (128-128) on the same 367k samples: 5/16 with ``uvms-v1``,
15/16 with ``uvms-v2``. A variant holding at rest (v_d = 0: 10x fewer operations, ~2 us
faster per decision) reached 12/16 by BC and 10/16 after DAgger (``uvms-v2``: 15/16).

``raw`` feeds the observation unchanged (any dimension).

Decisions: ``CompiledInputs`` evaluates features, normalization and clipping as one
generated-C function through preallocated buffers (~2.5 us with a_ss, ~1 us without;
the same feature code in Python costs 10-17 us). ``decision`` builds the same function
with the network's layers and output in it, so that a decision is one call.

The numpy ``featurize`` is the independent twin of ``featurize_sx``, and the expert's
compiled a_ss that of ``steady_sx``; the tests check that they agree.

May import: numpy, casadi, ``uvms_env.dynamics`` and ``nmpc_expert.ocp`` /
``nmpc_expert.local_model`` (the expert's model functions, not its controller).
"""

from __future__ import annotations

import functools
import math

import casadi as cs
import numpy as np

from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compile_function

FEATURES = ("raw", "uvms-v1", "uvms-v2")
FEEDFORWARD = ("uvms-v2",)  # feature sets whose last 8 numbers are the steady input
OBS_DIM = 79
FEATURE_DIMS = {"uvms-v1": 76, "uvms-v2": 84}
FEATURE_DIM = FEATURE_DIMS["uvms-v1"]
ACT_DIM = 8
OBSTACLE_RANGE = 5.0  # m; obstacle offsets beyond this are scaled down to it
INPUT_CLIP = 10.0  # normalized inputs are clipped to +-10 standard deviations


def check_features(features: str) -> None:
    if features not in FEATURES:
        raise ValueError(f"features must be one of {FEATURES}, got {features!r}")


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def featurize(obs: np.ndarray) -> np.ndarray:
    """(..., 79) observations -> (..., 76) float32 ``uvms-v1`` features (numpy)."""
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


def _wrap_sx(a: cs.SX) -> cs.SX:
    return a - 2 * math.pi * cs.floor((a + math.pi) / (2 * math.pi))


def featurize_sx(o: cs.SX) -> cs.SX:
    """(79,) observation -> (76,) ``uvms-v1`` features, symbolically (see network.py)."""
    psi = o[5]
    c, s = cs.cos(psi), cs.sin(psi)

    def heading(x: cs.SX, y: cs.SX) -> list[cs.SX]:
        return [c * x + s * y, -s * x + c * y]

    px, py, pz = o[20], o[21], o[22]
    f: list[cs.SX] = [o[k] for k in range(2, 5)] + [o[k] for k in range(6, 20)]
    f += [o[22], o[23], o[24], _wrap_sx(o[25] - psi)]
    for i in (26, 29):
        f += [*heading(o[i], o[i + 1]), o[i + 2]]
    for i in (32, 38):
        f += [*heading(o[i] - px, o[i + 1] - py), o[i + 2] - pz]
        f += [_wrap_sx(o[i + 3 + k] - o[23 + k]) for k in range(3)]
    f += [*heading(o[44], o[45]), o[46], o[47], o[48], o[49]]
    for i in (50, 55, 60):
        present = o[i + 3] > 0
        dist = cs.sqrt(o[i] ** 2 + o[i + 1] ** 2)
        scale = cs.fmin(1.0, OBSTACLE_RANGE / cs.fmax(dist, 1e-9))
        near = [*heading(o[i] * scale, o[i + 1] * scale), o[i + 2], o[i + 3], o[i + 4]]
        f += [cs.if_else(present, v, 0.0) for v in near]
    f += [*heading(o[0] - px, o[1] - py), o[2] - pz]
    f += [o[k] for k in range(65, 78)]
    out = cs.vertcat(*f)
    assert out.numel() == FEATURE_DIM
    return out


@functools.cache
def _steady_input(ring_radius: float) -> cs.Function:
    """The expert's a_ss(x, theta, v_d) for the bar (``ring_radius`` 0) or a ring."""
    from nmpc_expert.local_model import build_local_model
    from nmpc_expert.ocp import build_steady_input
    from uvms_env.dynamics.uvms import default_model

    uvms, obj = default_model(), _object(ring_radius)
    return build_steady_input(uvms, obj, build_local_model(uvms, obj))


def _object(ring_radius: float) -> ObjectModel:
    return ObjectModel("ring", ring_radius) if ring_radius > 0 else ObjectModel("bar")


def steady_sx(o: cs.SX, ring_radius: float) -> cs.SX:
    """a_ss (8) of the robot in observation ``o``: own q and zeta, own grasp and share,
    the object's nominal parameters, the observed navigation twist."""
    r_t = cs.reshape(o[69:78], 3, 3)  # the observation holds R_Oi row-major: this is R^T
    theta = cs.vertcat(  # laid out as nmpc_expert.local_model.ModelParams.pack
        o[66:69],
        cs.reshape(r_t.T, 9, 1),  # R_Oi column-major
        o[65],
        cs.DM(_object(ring_radius).nominal_parameters()),
    )
    return _steady_input(ring_radius)(o[0:20], theta, o[44:50])


def features_sx(o: cs.SX, features: str, ring_radius: float) -> cs.SX:
    check_features(features)
    if features == "raw":
        return o
    base = featurize_sx(o)
    return cs.vertcat(base, steady_sx(o, ring_radius)) if features in FEEDFORWARD else base


def inputs_sx(
    features: str, ring_radius: float, dim: int
) -> tuple[list[cs.SX], cs.SX, cs.SX | cs.DM, str]:
    """Symbolic inputs [obs, mean, inv_std, clip], the normalized clipped features z, the
    steady input (zeros for feature sets without it) and a tag for function names."""
    o = cs.SX.sym("obs", dim)
    x = features_sx(o, features, ring_radius)
    n = x.numel()
    mean, inv_std, clip = cs.SX.sym("mean", n), cs.SX.sym("inv_std", n), cs.SX.sym("clip")
    z = cs.fmin(clip, cs.fmax(-clip, (x - mean) * inv_std))
    ff = x[n - ACT_DIM :] if features in FEEDFORWARD else cs.DM.zeros(ACT_DIM)
    tag = f"{features}_{ring_radius:.4f}_{dim}".replace(".", "p").replace("-", "")
    return [o, mean, inv_std, clip], z, ff, tag


@functools.cache
def input_function(features: str, ring_radius: float, dim: int = OBS_DIM) -> cs.Function:
    """Compiled (obs, mean, inv_std, clip) -> [z; 1; a_ss]: the normalized clipped
    features z, a constant 1 (the MLP's bias input, see ``policy``) and the steady input
    (zeros for feature sets without it), in one vector so a decision copies it once."""
    args, z, ff, tag = inputs_sx(features, ring_radius, dim)
    fn = cs.Function(f"cloned_inputs_{tag}", args, [cs.vertcat(z, 1.0, ff)], {"cse": True})
    return compile_function(fn)


def object_ring(ring_radius: float | None, features: str) -> float:
    """The object argument of the compiled functions (0 for the bar or unused)."""
    if features in FEEDFORWARD and ring_radius is None:
        raise ValueError(f"{features} features need the object (ring radius, 0 for the bar)")
    return float(ring_radius or 0.0)


def input_dim(features: str, n_features: int) -> int:
    """The observation length of the compiled functions (``raw`` takes any)."""
    return OBS_DIM if features != "raw" else n_features


class CompiledInputs:
    """``__call__(obs)`` through a compiled function of (obs, mean, inv_std, clip): by
    default ``[z; 1; a_ss]`` (``input_function``); ``fn``: another function of the same
    inputs, e.g. a network's whole decision (``decision.decision_function``). Returns a
    float64 view of the output buffer, overwritten by the next call."""

    def __init__(
        self,
        features: str,
        mean: np.ndarray,
        inv_std: np.ndarray,
        ring_radius: float | None = None,
        clip: float = INPUT_CLIP,
        fn: cs.Function | None = None,
    ) -> None:
        dim = input_dim(features, len(mean))
        if fn is None:
            fn = input_function(features, object_ring(ring_radius, features), dim)
        self._call = BufferCall(fn)
        self._obs = np.zeros(dim)
        self._consts = (
            np.ascontiguousarray(mean, dtype=np.float64),
            np.ascontiguousarray(inv_std, dtype=np.float64),
            np.array([clip], dtype=np.float64),
        )
        self._out = self._call(self._obs, *self._consts)[0][0]  # binds every buffer once

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if obs.shape != self._obs.shape:
            raise ValueError(f"observation must have shape {self._obs.shape}, got {obs.shape}")
        self._obs[:] = obs  # one copy, with the float64 conversion
        self._call.again()
        return self._out


def prepare(
    obs: np.ndarray, features: str, ring_radius: np.ndarray | float | None = None
) -> np.ndarray:
    """(M, 79) observations -> (M, F) float32 features; ``ring_radius`` per sample (or one
    value) for the feature sets that need the object."""
    check_features(features)
    obs = np.asarray(obs)
    if features == "raw":
        return obs.astype(np.float32)
    base = featurize(obs)
    if features not in FEEDFORWARD:
        return base
    if ring_radius is None:
        raise ValueError(f"{features} features need the object (ring radius, 0 for the bar)")
    single = obs.ndim == 1
    o2 = np.atleast_2d(obs).astype(np.float64)
    rings = np.broadcast_to(np.asarray(ring_radius, dtype=np.float64), (len(o2),))
    if np.isnan(rings).any():
        raise ValueError(
            f"{features} features need the object of every sample; "
            f"{int(np.isnan(rings).sum())} samples come from data that did not record it "
            "(object_ring_radius): collect them again"
        )
    steady = np.zeros((len(o2), ACT_DIM), dtype=np.float32)
    for ring in np.unique(rings):
        rows = np.flatnonzero(rings == ring)
        mapped = _steady_batch(float(ring)).map(len(rows))
        steady[rows] = np.asarray(mapped(o2[rows].T)).T
    out = np.concatenate([np.atleast_2d(base), steady], axis=1)
    return out[0] if single else out


@functools.cache
def _steady_batch(ring_radius: float) -> cs.Function:
    """a_ss alone, for training batches: mapped over 50k samples it costs 0.8 s, the
    whole input function 2.0 s (the features come from the numpy ``featurize``)."""
    o = cs.SX.sym("obs", OBS_DIM)
    name = f"cloned_steady_{ring_radius:.4f}".replace(".", "p")
    return compile_function(cs.Function(name, [o], [steady_sx(o, ring_radius)]))
