"""Priors a user may switch on: what each robot can compute from its own observation and
what it knows before the task, offered to learning as an action or observation option.

``steady_inputs`` (a_ss, the expert's own input reference from
``uvms_env.dynamics.local_model.build_steady_input``), ``featurize`` (76 numbers in the
robot's own heading frame) and ``Priors`` (the options ``action_mode`` (torque, residual
around a_ss, or set-points of the robot's actuated velocities tracked around a_ss),
``observation_mode``, ``hold_stiffness``, ``hold_damping`` and the set-point loop's
gains). The single and the batched environment and the trained policies all call this
class, so an option means the same everywhere.

Why priors: a policy starting at zero torque drifts under weight and buoyancy, and the
holding forces depend on the grasp geometry and load share through the arm's kinematics,
which a network must otherwise learn from the geometries it happens to see. They are
priors, not the task: the plain setting (torque, raw) stays the default.
Reference: docs/environment.md ("Priors", "Memory"), docs/options.md.

May import: numpy, casadi, ``uvms_env.dynamics`` and ``uvms_env.scenarios`` (the nominal
arm pose).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

from uvms_env.dynamics import NU, ObjectModel
from uvms_env.dynamics.compiled import BufferCall, compile_function
from uvms_env.dynamics.local_model import build_local_model, build_steady_input
from uvms_env.dynamics.payload import object_tag
from uvms_env.dynamics.spatial import wrap_angle_sx
from uvms_env.dynamics.uvms import default_model
from uvms_env.robot.observation import OBSERVATION_SIZE, OBSERVATION_STRUCTURE
from uvms_env.scenarios.geometry import NOMINAL_ARM

OBS_DIM = OBSERVATION_SIZE  # the raw observation
ACT_DIM = NU  # the action
BASE_FEATURES = 76  # featurize
FEATURES_SIZE = BASE_FEATURES + ACT_DIM  # observation_mode="features": featurize and a_ss
OBSTACLE_RANGE = 5.0  # m; obstacle offsets beyond this are scaled down to it
# the arm's joint angles (q's last 4) and rates (zeta's last 4) in the observation
_JOINTS = slice(OBSERVATION_STRUCTURE["q"].start + 6, OBSERVATION_STRUCTURE["q"].stop)
_JOINT_RATES = slice(OBSERVATION_STRUCTURE["zeta"].start + 6, OBSERVATION_STRUCTURE["zeta"].stop)
_ZETA = OBSERVATION_STRUCTURE["zeta"]
ACTION_MODES = ("torque", "residual", "setpoint")
# action_mode="setpoint": the action's 8 numbers are set-points of the robot's actuated
# velocities, each normalized by its limit: surge, sway, heave (m/s, by the linear vehicle
# speed limit), yaw rate (rad/s, by the angular one) and the 4 joint rates (by the joint
# speed limit); these are zeta's entries (body twist u v w, r, then the joint rates).
SETPOINT_ZETA = (0, 1, 2, 5, 6, 7, 8, 9)
# The set-point loop, closed once per period on the robot's measured velocities, around
# the steady input that holds the robot still with its share of the load (a_ss at a zero
# navigation twist). The vehicle's gain on each of its inputs is its own inertia on that
# velocity over ``setpoint_time``: one gain for all made the yaw ring at a gain the surge
# barely felt (0.73 kg m^2 of yaw inertia against 21 kg of surge mass, a 0.12 s period).
# The joints' own inertia (0.05-0.07 kg m^2) says little in the closed chain, where a
# joint moves the object and the teammates: their gain is one number, the largest a probe
# of zero, surge, yaw and joint-rate set-points on ``short`` kept stable (0.2 rang at the
# joint-rate limit; docs/environment.md, "Set-points").
DEFAULT_SETPOINT_TIME = 0.5  # s
DEFAULT_SETPOINT_JOINT_GAIN = 0.05  # normalized torque per joint-rate error of one limit
OBSERVATION_MODES = ("raw", "features", "memory")
# observation_mode="memory": featurize, the robot's memory (uvms_env.robot.memory: the last
# command and the disturbance estimate, 16), then a_ss (last, as in "features")
MEMORY_BLOCK = 2 * ACT_DIM
MEMORY_FEATURES_SIZE = BASE_FEATURES + MEMORY_BLOCK + ACT_DIM
# Residual reach 0.3 of the saturation: enough to correct a_ss (the expert's inputs stay
# within ~0.25 of it on the paper scenario) while a uniformly random residual still holds
# the object (a_ss alone succeeds on short and random N = 2).
DEFAULT_RESIDUAL_SCALE = 0.3
# Rows per compiled call over a dataset (``_rows``): the call's buffers stay ~5 MB.
ROW_CHUNK = 8192


def featurize(obs: np.ndarray) -> np.ndarray:
    """(..., 79) observations -> (..., 76) float32 ``uvms-v1`` features: ``featurize_sx``
    compiled, the one implementation (the batched kernels evaluate the same expression)."""
    o = np.asarray(obs)  # converted to float64 chunk by chunk (``_rows``)
    if o.shape[-1] != OBS_DIM:
        raise ValueError(f"uvms-v1 features need {OBS_DIM}-number observations, got {o.shape}")
    out = _rows(_features_call, o.reshape(-1, OBS_DIM), BASE_FEATURES, np.float32)
    return out.reshape(*o.shape[:-1], BASE_FEATURES)


def _rows(call: Any, flat: np.ndarray, width: int, dtype: Any) -> np.ndarray:
    """A compiled row function over every row of ``flat`` (M, 79), ``ROW_CHUNK`` rows per
    call (``call(count)``: the cached call of ``count`` rows): a dataset of millions of
    rows needs no buffers of its size, and the cache holds calls of bounded size."""
    if 0 < len(flat) <= ROW_CHUNK:  # one call (a step's robots): no loop, one copy out
        return call(len(flat))(np.ascontiguousarray(flat, dtype=np.float64))[0].astype(dtype)
    out = np.empty((len(flat), width), dtype)
    for start in range(0, len(flat), ROW_CHUNK):
        part = np.ascontiguousarray(flat[start : start + ROW_CHUNK], dtype=np.float64)
        out[start : start + len(part)] = call(len(part))(part)[0]
    return out


def featurize_sx(o: cs.SX) -> cs.SX:
    """(79,) observation -> (76,) ``uvms-v1`` features, symbolically (see baselines/networks)."""
    at = {name: sl.start for name, sl in OBSERVATION_STRUCTURE.items()}
    q, pose, twist = at["q"], at["object_pose"], at["object_twist"]
    psi = o[q + 5]  # vehicle yaw
    c, s = cs.cos(psi), cs.sin(psi)

    def heading(x: cs.SX, y: cs.SX) -> list[cs.SX]:
        return [c * x + s * y, -s * x + c * y]

    px, py, pz = o[pose], o[pose + 1], o[pose + 2]
    f: list[cs.SX] = [o[q + k] for k in (2, 3, 4, 6, 7, 8, 9)]
    f += [o[at["zeta"] + k] for k in range(10)]
    f += [o[pose + 2], o[pose + 3], o[pose + 4], wrap_angle_sx(o[pose + 5] - psi)]
    for i in (twist, twist + 3):
        f += [*heading(o[i], o[i + 1]), o[i + 2]]
    for i in (at["waypoint"], at["goal"]):
        f += [*heading(o[i] - px, o[i + 1] - py), o[i + 2] - pz]
        f += [wrap_angle_sx(o[i + 3 + k] - o[pose + 3 + k]) for k in range(3)]
    nav = at["nav_velocity"]
    f += [*heading(o[nav], o[nav + 1]), o[nav + 2], o[nav + 3], o[nav + 4], o[nav + 5]]
    for i in range(at["obstacles"], at["obstacles"] + 15, 5):
        present = o[i + 3] > 0
        dist = cs.sqrt(o[i] ** 2 + o[i + 1] ** 2)
        scale = cs.fmin(1.0, OBSTACLE_RANGE / cs.fmax(dist, 1e-9))
        near = [*heading(o[i] * scale, o[i + 1] * scale), o[i + 2], o[i + 3], o[i + 4]]
        f += [cs.if_else(present, v, 0.0) for v in near]
    f += [*heading(o[q] - px, o[q + 1] - py), o[q + 2] - pz]
    f += [o[k] for k in range(at["load_share"], at["time_fraction"])]
    out = cs.vertcat(*f)
    assert out.numel() == BASE_FEATURES
    return out


@functools.cache
def _steady_input(object_key: float) -> cs.Function:
    """The expert's a_ss(x, theta, v_d) for the object ``object_key`` (its key)."""
    uvms, obj = default_model(), object_model(object_key)
    return build_steady_input(uvms, obj, build_local_model(uvms, obj))


def object_model(object_key: float) -> ObjectModel:
    """The carried object by the compiled functions' name for it, its key
    (``uvms_env.dynamics.payload.object_key``: a ring's radius, 0 for the parameter
    file's bar, minus the length for another bar)."""
    return ObjectModel.from_key(object_key)


def own_model_inputs(o: cs.SX, object_key: float) -> tuple[cs.SX, cs.SX]:
    """(x, theta) of the robot's local model from its observation ``o``: own q and zeta,
    own grasp and load share and the object's nominal parameters (known before the task)."""
    f = OBSERVATION_STRUCTURE
    # the observation holds R_Oi row-major: this is R^T
    r_t = cs.reshape(o[f["grasp_rotation"]], 3, 3)
    theta = cs.vertcat(  # laid out as uvms_env.dynamics.local_model.ModelParams.pack
        o[f["grasp_offset"]],
        cs.reshape(r_t.T, 9, 1),  # R_Oi column-major
        o[f["load_share"]],
        cs.DM(object_model(object_key).nominal_parameters()),
    )
    return o[f["q"].start : f["zeta"].stop], theta


def steady_sx(o: cs.SX, object_key: float) -> cs.SX:
    """a_ss (8) of the robot in observation ``o``: own q and zeta, own grasp and share,
    the object's nominal parameters, the observed navigation twist."""
    own, theta = own_model_inputs(o, object_key)
    return _steady_input(object_key)(own, theta, o[OBSERVATION_STRUCTURE["nav_velocity"]])


@functools.cache
def _steady_one(object_key: float) -> cs.Function:
    """a_ss alone, compiled (the features are ``featurize``'s own call)."""
    o = cs.SX.sym("obs", OBS_DIM)
    name = f"prior_steady_{object_tag(object_key)}"
    return compile_function(cs.Function(name, [o], [steady_sx(o, object_key)]))


@functools.cache
def _features_one() -> cs.Function:
    o = cs.SX.sym("obs", OBS_DIM)
    return compile_function(cs.Function("prior_features", [o], [featurize_sx(o)]))


@functools.lru_cache(maxsize=16)
def _features_call(count: int) -> BufferCall:
    return BufferCall(_features_one().map(count))


@functools.cache
def prior_functions(object_key: float) -> tuple[cs.Function, cs.Function]:
    """(a_ss, features) of one (79,) observation as CasADi functions, for batched
    kernels (the GPU backend evaluates them over every robot's column)."""
    o = cs.SX.sym("obs", OBS_DIM)
    tag = object_tag(object_key)
    steady = cs.Function(f"prior_steady_{tag}", [o], [steady_sx(o, object_key)])
    return steady, cs.Function("prior_features", [o], [featurize_sx(o)])


@functools.lru_cache(maxsize=16)
def _steady_call(object_key: float, count: int) -> BufferCall:
    # The buffer interface: an ordinary call's conversions cost more than the evaluation.
    return BufferCall(_steady_one(object_key).map(count))


def steady_inputs(obs: np.ndarray, object_key: float) -> np.ndarray:
    """(..., 79) observations of robots carrying one object -> (..., 8) float64 a_ss."""
    o = np.asarray(obs)
    if o.shape[-1] != OBS_DIM:
        raise ValueError(f"steady inputs need {OBS_DIM}-number observations, got {o.shape}")
    call = functools.partial(_steady_call, float(object_key))
    return _rows(call, o.reshape(-1, OBS_DIM), ACT_DIM, np.float64).reshape(*o.shape[:-1], ACT_DIM)


@functools.cache
def setpoint_inertia() -> np.ndarray:
    """(8,) the robot's own generalized inertia on each actuated velocity
    (``SETPOINT_ZETA``: the diagonal of its mass matrix with the added mass, at the nominal
    arm pose; kg and kg m^2), the object and the teammates left out."""
    uvms = default_model()
    q = np.concatenate([np.zeros(6), NOMINAL_ARM])
    mass = np.array(uvms.mass_matrix(q, uvms.nominal_parameters()))
    return np.diag(mass)[list(SETPOINT_ZETA)]


def _tau_max() -> np.ndarray:
    return np.asarray(default_model().params.limits.tau_max, dtype=float)


@functools.cache
def setpoint_limits() -> np.ndarray:
    """(8,) the limits that scale a set-point action (``SETPOINT_ZETA``'s order), from the
    limits' one source: linear vehicle speed (u, v, w), angular (r), joint speed (4)."""
    lim = default_model().params.limits
    v, w, j = lim.vehicle_linear_speed, lim.vehicle_angular_speed, lim.joint_speed
    return np.array([v, v, v, w, j, j, j, j])


def check_mode(name: str, value: object, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return str(value)


@dataclass(frozen=True)
class Priors:
    """The action and observation options. ``observe`` and ``command`` take (..., 79) raw
    observations of any leading shape (robots, environments x robots) of robots that
    carry one object (``object_key``: its key, ``Scenario.object_key``)."""

    action_mode: str = "torque"
    observation_mode: str = "raw"
    residual_scale: float = DEFAULT_RESIDUAL_SCALE
    hold_stiffness: float = 0.0
    hold_damping: float = 0.0
    setpoint_time: float = DEFAULT_SETPOINT_TIME
    setpoint_joint_gain: float = DEFAULT_SETPOINT_JOINT_GAIN

    def __post_init__(self) -> None:
        check_mode("action_mode", self.action_mode, ACTION_MODES)
        check_mode("observation_mode", self.observation_mode, OBSERVATION_MODES)
        if not (math.isfinite(self.residual_scale) and 0.0 < self.residual_scale <= 2.0):
            raise ValueError(f"residual_scale must be in (0, 2], got {self.residual_scale!r}")
        for name in ("hold_stiffness", "hold_damping"):
            gain = getattr(self, name)
            if not (math.isfinite(gain) and 0.0 <= gain <= 10.0):
                raise ValueError(f"{name} must be in [0, 10], got {gain!r}")
        if self.holds and self.action_mode != "residual":
            raise ValueError("hold_stiffness and hold_damping act in action_mode='residual' only")
        if not (math.isfinite(self.setpoint_time) and 0.05 <= self.setpoint_time <= 10.0):
            raise ValueError(f"setpoint_time must be in [0.05, 10] s, got {self.setpoint_time!r}")
        gain = self.setpoint_joint_gain
        if not (math.isfinite(gain) and 0.0 < gain <= 1.0):
            raise ValueError(f"setpoint_joint_gain must be in (0, 1], got {gain!r}")

    @property
    def holds(self) -> bool:
        return self.hold_stiffness > 0.0 or self.hold_damping > 0.0

    @property
    def plain(self) -> bool:
        return self.action_mode == "torque" and self.observation_mode == "raw"

    @property
    def observation_size(self) -> int:
        return {"features": FEATURES_SIZE, "memory": MEMORY_FEATURES_SIZE}.get(
            self.observation_mode, OBS_DIM
        )

    @property
    def remembers(self) -> bool:
        """The observation carries the robot's memory (``uvms_env.robot.memory``)."""
        return self.observation_mode == "memory"

    @property
    def needs_steady(self) -> bool:
        return not self.plain

    def observe(
        self,
        raw: np.ndarray,
        object_key: float,
        steady: np.ndarray | None = None,
        memory: np.ndarray | None = None,
    ) -> np.ndarray:
        """What the policy sees: the raw observation, or its features (with the robot's
        ``memory`` block in the memory mode) and a_ss, float32. ``steady``: a_ss of ``raw``
        when the caller has it already."""
        if self.observation_mode == "raw":
            return raw
        if steady is None:
            steady = steady_inputs(raw, object_key)
        parts = [featurize(raw), steady]
        if self.remembers:
            if memory is None:
                raise ValueError("observation_mode='memory' needs the robot's memory block")
            parts.insert(1, memory)
        return np.concatenate(parts, -1).astype(np.float32)

    def command(
        self,
        raw: np.ndarray,
        action: np.ndarray,
        object_key: float,
        steady: np.ndarray | None = None,
    ) -> np.ndarray:
        """The normalized input for ``action`` of robots whose last observation is ``raw``:
        the action itself (torque), clip(a_ss + s clip(action, -1, 1), -1, 1) (residual),
        or the set-point loop's clip(a_ss + K (clip(action, -1, 1) - zeta_a / limit), -1, 1)
        (setpoint: ``zeta_a`` the robot's measured actuated velocities, ``SETPOINT_ZETA``;
        ``K``: ``setpoint_gains``). ``steady``: a_ss of ``steady_source(raw)`` when the
        caller has it."""
        if self.action_mode == "torque":
            return action
        if steady is None:
            steady = steady_inputs(self.steady_source(raw), object_key)
        if self.action_mode == "setpoint":
            speed = raw[..., _ZETA][..., list(SETPOINT_ZETA)] / setpoint_limits()
            return self._setpoint(steady, action, speed, np.minimum, np.maximum)
        base = steady + self.joint_hold(raw) if self.holds else steady
        return self._residual(base, action, np.minimum, np.maximum)

    @property
    def setpoint_gains(self) -> np.ndarray:
        """K (8,): per actuated velocity, normalized input per set-point error of one whole
        limit: on the vehicle's four the robot's own inertia on it (``setpoint_inertia``)
        times the limit over ``setpoint_time`` and the input's saturation; on the joints'
        ``setpoint_joint_gain``."""
        vehicle = setpoint_inertia() * setpoint_limits() / (self.setpoint_time * _tau_max())
        return np.concatenate([vehicle[:4], np.full(4, self.setpoint_joint_gain)])

    def steady_source(self, raw: Any) -> Any:
        """The observation whose a_ss the command is built around: ``raw`` itself, or in
        the setpoint mode ``raw`` with its navigation twist zeroed (the input that holds
        the robot still with its share of the load). Any array type, CasADi's included."""
        if self.action_mode != "setpoint":
            return raw
        nav = OBSERVATION_STRUCTURE["nav_velocity"]
        if isinstance(raw, cs.MX | cs.SX):
            return cs.vertcat(
                raw[: nav.start], type(raw).zeros(nav.stop - nav.start), raw[nav.stop :]
            )
        out = raw.copy()
        out[..., nav] = 0.0
        return out

    def _setpoint(self, steady: Any, action: Any, speed: Any, fmin: Any, fmax: Any) -> Any:
        """clip(a_ss + K (clip(action, -1, 1) - speed), -1, 1), ``speed`` the measured
        actuated velocities over their limits, in any namespace: the one writing of the
        loop."""
        target = fmin(1.0, fmax(-1.0, action))
        return fmin(1.0, fmax(-1.0, steady + self.setpoint_gains * (target - speed)))

    def _residual(self, base: Any, action: Any, fmin: Any, fmax: Any) -> Any:
        """clip(base + s clip(action, -1, 1), -1, 1) with the namespace's own min and max
        (numpy's and CuPy's arrays, CasADi's symbols): the one writing of the transform."""
        a = fmin(1.0, fmax(-1.0, action))
        return fmin(1.0, fmax(-1.0, base + self.residual_scale * a))

    def joint_hold(self, raw: np.ndarray) -> np.ndarray:
        """h (..., 8): zero on the vehicle's four inputs (surge, sway, heave, yaw), the
        joint hold on the arm's four.
        Written with scalars and slices only, so that it runs on any array library
        (numpy here, CuPy through the GPU backend)."""
        q, rate = raw[..., _JOINTS], raw[..., _JOINT_RATES]
        arm = [self._hold(q[..., j], rate[..., j], j) for j in range(4)]
        zero = 0.0 * q[..., 0]
        return np.stack([zero] * (ACT_DIM - 4) + arm, -1).astype(np.float64)

    def _hold(self, q: Any, rate: Any, j: int) -> Any:
        """h_j of arm joint j at angle ``q`` and rate ``rate`` (any array or CasADi type)."""
        return -self.hold_stiffness * (q - float(NOMINAL_ARM[j])) - self.hold_damping * rate

    def command_sx(self, o: cs.SX, action: cs.SX, steady: cs.SX) -> cs.SX:
        """``command`` of one symbolic (79,) observation ``o`` with its a_ss ``steady``
        (that of ``steady_source(o)``), for compiled decisions
        (``baselines.networks.ppo_decision``); ``action`` is clipped here."""
        if self.action_mode == "torque":
            return cs.fmin(1.0, cs.fmax(-1.0, action))
        if self.action_mode == "setpoint":
            zeta = _ZETA.start
            speed = cs.vertcat(*[o[zeta + k] for k in SETPOINT_ZETA]) / cs.DM(setpoint_limits())
            return self._setpoint(steady, action, speed, cs.fmin, cs.fmax)
        base = steady
        if self.holds:
            q, rate = _JOINTS.start, _JOINT_RATES.start
            arm = [self._hold(o[q + j], o[rate + j], j) for j in range(4)]
            base = base + cs.vertcat(cs.DM.zeros(ACT_DIM - 4), *arm)
        return self._residual(base, action, cs.fmin, cs.fmax)
