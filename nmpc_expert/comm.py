"""``TalkingNMPCPolicy`` (``--policy nmpc:comm``): the distributed expert with messages.

The default (observer) expert, plus an acoustic channel (``uvms_env.robot.channel``): every
period each robot broadcasts its disturbance estimate on its vehicle's linear rates,
rotated into the world frame, and fuses what it receives into the team's mean estimate,
which replaces its own estimate in the steady-input shift (``observer_input_gain``); the
prediction model keeps each robot's own estimate. Why the mean, the message's numbers
(``encode_message``; ``decode_message`` and ``decode_sender`` invert it) and the fusion
(``age_weight``; of one sender only the newest message counts, so without a sender
number, at ``message_dim`` 3, a sender may count twice; ``own_share``) are written once,
in docs/channel.md, "The talking expert". **No usable message: exactly the silent expert**
(its own estimate, bit for bit; tested).

Needs a channel: built from a spec without one (``AgentSpec.comm`` None) it raises, as it
does when ``message_dim`` < ``MESSAGE_NUMBERS``.

May import: numpy, casadi, ``uvms_env`` (policy, dynamics, robot.observation,
robot.channel) and this package. Never ``baselines``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as cs
import numpy as np

from nmpc_expert.local_controller import NMPCPolicy
from nmpc_expert.observation_reader import OBSERVATION_SIZE
from nmpc_expert.settings import NMPCSettings, controller_settings
from uvms_env.dynamics import NU
from uvms_env.dynamics.local_model import NX
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.policy import AgentSpec

MESSAGE_NUMBERS = 3  # the world-frame disturbance on the vehicle's linear rates
MESSAGE_SCALE_LIMITS = 0.2  # message unit, in vehicle linear speed limits per period
SENDER_LEVELS = 16  # sender indices the 4th number tells apart (needs >= 4 bits)
# the age weights: what a message mostly carries, the current, changes over seconds, so a
# message of a slow modem (80 bit/s: ~9 periods of delay, each robot heard every 5 N
# periods) still counts; a teammate's pull changes faster, hence the fade
FRESH_PERIODS = 4  # a message this old (or younger) counts fully (0.5 s)
STALE_PERIODS = 25  # a message this old (or older) is ignored (3 s)
SEND = 1.0  # the send flag: every period (the channel's TDMA decides when it goes out)
_VEHICLE_ATTITUDE = slice(3, 6)  # q's ZYX Euler angles of the vehicle (local model)


def message_scale(settings: NMPCSettings) -> float:
    """The message's unit: ``MESSAGE_SCALE_LIMITS`` vehicle linear speed limits, m/s (a
    velocity change per period). Under a mild current the estimates stay below 0.1
    limits; the observer's own clip (``observer_limit``, 5 limits) is far wider, but a
    unit that wide would spend the 8-bit presets' levels on values that do not occur."""
    return MESSAGE_SCALE_LIMITS * settings.vehicle_speed[0]


def age_weight(age_periods: np.ndarray) -> np.ndarray:
    """w(a): 1 up to ``FRESH_PERIODS``, linear to 0 at ``STALE_PERIODS``, 0 beyond."""
    a = np.asarray(age_periods, dtype=float)
    return np.clip((STALE_PERIODS - a) / (STALE_PERIODS - FRESH_PERIODS), 0.0, 1.0)


def attitude(q: np.ndarray) -> np.ndarray:
    """R (3, 3), the vehicle's body -> world rotation from its ZYX Euler angles in q."""
    return np.array(cs.DM(rot_zyx(cs.DM(q[_VEHICLE_ATTITUDE]))), dtype=float)


def encode_message(d_world: np.ndarray, scale: float, message_dim: int, sender: int) -> np.ndarray:
    """The ``message_dim`` numbers of a world-frame estimate and, when there is room, the
    sender's index (docs/channel.md, "The talking expert")."""
    m = np.zeros(message_dim)
    m[:MESSAGE_NUMBERS] = np.clip(np.asarray(d_world, float) / scale, -1.0, 1.0)
    if message_dim > MESSAGE_NUMBERS:
        m[MESSAGE_NUMBERS] = -1.0 + 2.0 * (sender % SENDER_LEVELS) / (SENDER_LEVELS - 1)
    return m


def decode_sender(message: np.ndarray) -> int | None:
    """The sender's index (modulo ``SENDER_LEVELS``) a message names; None without room."""
    if len(message) <= MESSAGE_NUMBERS:
        return None
    return int(np.rint((message[MESSAGE_NUMBERS] + 1.0) / 2.0 * (SENDER_LEVELS - 1)))


def decode_message(message: np.ndarray, scale: float) -> np.ndarray:
    """The world-frame estimate (3,) a message carries (as quantized by the channel)."""
    return np.asarray(message, dtype=float)[:MESSAGE_NUMBERS] * scale


class TalkingNMPCPolicy(NMPCPolicy):
    """The observer expert that broadcasts its disturbance estimate and shifts its steady
    input by the team's mean (module docstring)."""

    reads_messages = True

    def __init__(
        self,
        spec: AgentSpec,
        solver: str = "rti",
        settings: NMPCSettings | None = None,
        own_share: float = 0.0,
    ) -> None:
        comm = spec.comm
        if comm is None:
            raise ValueError(
                "nmpc:comm talks over an acoustic channel and the environment has none: "
                "give it one (parallel_env(..., comm=PRESET), --comm PRESET) or play the "
                "silent expert, nmpc"
            )
        if comm.message_dim < MESSAGE_NUMBERS:
            raise ValueError(
                f"nmpc:comm sends {MESSAGE_NUMBERS} numbers per message; the channel's "
                f"message_dim is {comm.message_dim}"
            )
        if not 0.0 <= own_share <= 1.0:
            raise ValueError(f"own_share must lie in [0, 1], got {own_share}")
        super().__init__(spec, solver, settings)
        if not self.settings.disturbance_observer or self.settings.observer_input_gain <= 0:
            raise ValueError(
                "nmpc:comm shares the disturbance observer's estimate for the steady-input "
                "shift: it needs disturbance_observer and observer_input_gain > 0"
            )
        self.comm = comm
        self.own_share = own_share
        self.scale = message_scale(self.settings)
        self._rotation: np.ndarray | None = None  # this period's attitude, once computed
        self._received = np.zeros((0, 3))  # fresh world-frame estimates of the teammates
        self._weights = np.zeros(0)
        self.message = np.zeros(comm.message_dim)  # the last message sent
        self.fused: np.ndarray | None = None  # the body-frame estimate the shift used

    def reset(self) -> None:
        super().reset()
        self._received = np.zeros((0, 3))
        self._weights = np.zeros(0)
        self.message = np.zeros(self.comm.message_dim)
        self.fused = None

    def act(self, obs: np.ndarray) -> np.ndarray:
        o = np.asarray(obs)
        c = self.comm
        if o.shape != (OBSERVATION_SIZE + c.block_size,):
            raise ValueError(
                f"nmpc:comm expects an observation of {OBSERVATION_SIZE} + the inbox's "
                f"{c.block_size} numbers, got shape {o.shape}"
            )
        self._read_inbox(o[OBSERVATION_SIZE:].astype(np.float64))
        self._rotation = None
        action = super().act(o[:OBSERVATION_SIZE])
        # the estimate just updated (this period's innovation), in the world frame
        d_world = self._attitude() @ self.disturbance[:3]
        self.message = encode_message(d_world, self.scale, c.message_dim, self.spec.index)
        self.stats["messages_used"] = len(self._weights)
        self.stats["message_weight"] = float(self._weights.sum())
        # float32 as the silent team's actions go out (``uvms_env.episode.SilentPolicy``):
        # with no message the same inputs, bit for bit
        return np.concatenate([action, [SEND], self.message]).astype(np.float32)

    def executed(self, action: np.ndarray) -> None:
        """The input applied (``LocalController.executed``): the first 8 numbers of a
        full channel action, or the 8 inputs alone."""
        super().executed(np.asarray(action).reshape(-1)[:NU])

    def _read_inbox(self, inbox: np.ndarray) -> None:
        """The valid messages of the inbox young enough to use, and their weights."""
        c = self.comm
        slots = inbox.reshape(c.inbox_size, c.slot_size)
        valid = slots[:, c.message_dim + 1] > 0.5
        age = slots[:, c.message_dim] * c.max_age_periods
        w = np.where(valid, age_weight(age), 0.0)
        if c.message_dim > MESSAGE_NUMBERS:  # of one sender, the newest only
            seen: set[int | None] = {self.spec.index % SENDER_LEVELS}
            order = np.argsort(age, kind="stable")
            for k in order:
                if w[k] <= 0:  # an empty slot or a stale message names no one
                    continue
                sender = decode_sender(slots[k, : c.message_dim])
                if sender in seen:
                    w[k] = 0.0
                seen.add(sender)
        used = w > 0
        self._weights = w[used]
        self._received = np.array(
            [decode_message(m, self.scale) for m in slots[used, : c.message_dim]]
        ).reshape(-1, 3)

    def _input_disturbance(self) -> np.ndarray:
        """The team's mean estimate in this robot's body frame; its own (the silent
        expert's, the same array) when no message is usable."""
        if not len(self._weights):
            self.fused = None
            return self.disturbance
        rot = self._attitude()
        own = rot @ self.disturbance[:3]
        mean = (own + self._weights @ self._received) / (1.0 + self._weights.sum())
        fused = self.disturbance.copy()
        fused[:3] = rot.T @ (mean + self.own_share * (own - mean))
        self.fused = fused
        return fused

    def _attitude(self) -> np.ndarray:
        """This period's R (computed once, from the measured state)."""
        if self._rotation is None:
            self._rotation = attitude(self._x0[: NX // 2])
        return self._rotation


def make_talking_policy(
    solver: str = "rti", **settings: Any
) -> Callable[[AgentSpec], TalkingNMPCPolicy]:
    """A ``PolicyFactory`` (AgentSpec -> ``TalkingNMPCPolicy``) with the observer
    controller's settings and ``settings`` changed (unknown names: ValueError)."""
    unknown = sorted(set(settings) - set(NMPCSettings.field_names()))
    if unknown:
        raise ValueError(f"unknown NMPC setting(s) {unknown}; known: {NMPCSettings.field_names()}")
    cfg = controller_settings("observer", **settings)

    def factory(spec: AgentSpec) -> TalkingNMPCPolicy:
        return TalkingNMPCPolicy(spec, solver=solver, settings=cfg)

    return factory
