"""The acoustic channel: messages between the robots, an option of the environment.

``comm=None`` (default, or ``"off"``): the paper's silent team, nothing here runs. With a
channel (``comm=`` a preset name of ``PRESETS``, a ``ChannelSettings`` or a mapping
``{"preset": name, field: value, ...}``) each robot's action gains a send flag and a
message, and its observation a fixed-size inbox of what it received. ``EnvCore`` owns one
``Channel`` for its batch (B = () or (K,)): ``parallel_env`` and ``VectorEnv`` (cpu and
cuda) run this same array code.

The action and observation layouts and the model, per control period (quantization,
packets, the shared medium's TDMA slots, the outbox, delays, losses and their
counter-based randomness), are written once, in docs/channel.md.
``silent(actions, settings)`` pads 8-number actions with a silent message part.

May import: numpy and ``uvms_env.dynamics`` (sizes).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import NamespacePickled

CHANNEL_FILE = Path(__file__).resolve().parent.parent / "models" / "channel.toml"
HEADER_BITS = 16  # address, sequence number, checksum (per packet)
SEND = NU  # index of the send flag in a robot's action
OFF = ("off", "none")
_STREAM = 0x636F6D6D  # "comm": the channel generator's stream, apart from the env's
_U53 = 2.0**-53


def _load() -> tuple[float, dict[str, dict[str, Any]]]:
    raw = tomllib.loads(CHANNEL_FILE.read_text())
    presets = {
        name: {k: v for k, v in table.items() if k != "source"}
        for name, table in raw["presets"].items()
    }
    return float(raw["medium"]["sound_speed"]), presets


SOUND_SPEED, _PRESET_TABLES = _load()


@dataclass(frozen=True)
class ChannelSettings:
    """The acoustic channel's parameters (docs/channel.md); checked on construction."""

    message_dim: int = 4  # numbers per message, each in [-1, 1]
    bits_per_value: int = 8  # quantization of each number (1..32)
    bit_rate_bps: float = 2400.0  # the shared medium's rate, bit/s (inf: unlimited)
    modem_latency_periods: int = 0  # the modem's own latency per packet, periods
    propagation_delay: bool = True  # add range / sound speed to the latency
    loss_probability: float = 0.0  # p0: the loss floor, at any range
    loss_range_m: float = math.inf  # range of 50 % loss above p0 (inf: fixed p0)
    loss_width_m: float = 100.0  # the logistic's width in range, m
    max_range_m: float = 2000.0  # beyond it every delivery is lost
    inbox_size: int = 4  # M: messages kept in the observation
    max_age_periods: int = 50  # older messages leave the inbox; the age's scale

    def __post_init__(self) -> None:
        ints = {
            "message_dim": (1, 64),
            "bits_per_value": (1, 32),
            "modem_latency_periods": (0, 10_000),
            "inbox_size": (1, 64),
            "max_age_periods": (1, 1_000_000),
        }
        for name, (low, high) in ints.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise TypeError(f"comm: {name} must be an int, got {v!r}")
            if not low <= v <= high:
                raise ValueError(f"comm: {name} must lie in [{low}, {high}], got {v}")
        if not isinstance(self.propagation_delay, bool | np.bool_):
            raise TypeError(
                f"comm: propagation_delay must be a bool, got {self.propagation_delay!r}"
            )
        floats = ("bit_rate_bps", "loss_probability", "loss_range_m", "loss_width_m", "max_range_m")
        for name in floats:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
                raise TypeError(f"comm: {name} must be a number, got {v!r}")
            if math.isnan(v):
                raise ValueError(f"comm: {name} is NaN")
        if not self.bit_rate_bps > 0:
            raise ValueError(
                f"comm: bit_rate_bps must be > 0 (inf: unlimited), got {self.bit_rate_bps}"
            )
        if not 0.0 <= self.loss_probability <= 1.0:
            raise ValueError(
                f"comm: loss_probability must lie in [0, 1], got {self.loss_probability}"
            )
        if not self.loss_range_m > 0:
            raise ValueError(
                f"comm: loss_range_m must be > 0 (inf: fixed loss), got {self.loss_range_m}"
            )
        if not 0 < self.loss_width_m < math.inf:
            raise ValueError(f"comm: loss_width_m must be finite and > 0, got {self.loss_width_m}")
        if not 0 < self.max_range_m < math.inf:
            raise ValueError(f"comm: max_range_m must be finite and > 0, got {self.max_range_m}")
        if self.modem_latency_periods >= self.max_age_periods:
            # every message would leave the inbox before it could be read
            raise ValueError(
                f"comm: modem_latency_periods ({self.modem_latency_periods}) must be below "
                f"max_age_periods ({self.max_age_periods}): every message would expire in flight"
            )

    @property
    def packet_bits(self) -> int:
        return self.message_dim * self.bits_per_value + HEADER_BITS

    @property
    def action_size(self) -> int:
        """Numbers per robot's action: 8 inputs, the send flag, the message."""
        return NU + 1 + self.message_dim

    @property
    def slot_size(self) -> int:
        """Numbers per inbox slot: the message, its age, the valid flag."""
        return self.message_dim + 2

    @property
    def block_size(self) -> int:
        """Numbers the inbox adds to each robot's observation."""
        return self.inbox_size * self.slot_size

    def schedule(self, period: float) -> tuple[int, int]:
        """(s, P): s robots speak per period (s > 1 only when P = 1), a slot lasts P periods."""
        per_period = self.bit_rate_bps * period / self.packet_bits
        if per_period >= 1:
            return (int(min(per_period, 1 << 30)), 1)
        return 1, math.ceil(self.packet_bits / (self.bit_rate_bps * period) - 1e-12)

    def delay_periods(self, rng: Any, period: float, xp: Any = np) -> Any:
        """Delivery delays in periods at ranges ``rng`` (m)."""
        tx = self.packet_bits / self.bit_rate_bps  # 0 at an unlimited rate
        prop = rng / SOUND_SPEED if self.propagation_delay else 0.0 * rng
        return self.modem_latency_periods + xp.floor((tx + prop) / period).astype(np.int64)

    def max_delay(self, period: float) -> int:
        return int(self.delay_periods(np.array(self.max_range_m), period))

    def loss(self, rng: Any, xp: Any = np) -> Any:
        """Loss probability at ranges ``rng`` (m); 1 beyond ``max_range_m``."""
        p0 = self.loss_probability
        if math.isinf(self.loss_range_m):
            p = p0 + 0.0 * rng
        else:
            z = xp.clip((rng - self.loss_range_m) / self.loss_width_m, -60.0, 60.0)
            p = p0 + (1.0 - p0) / (1.0 + xp.exp(-z))
        return xp.where(rng > self.max_range_m, 1.0, p)

    def quantize(self, x: Any, xp: Any = np) -> Any:
        """Numbers clipped to [-1, 1] and rounded to ``bits_per_value`` bits."""
        levels = float((1 << self.bits_per_value) - 1)
        return xp.rint((xp.clip(x, -1.0, 1.0) + 1.0) * (levels / 2.0)) * (2.0 / levels) - 1.0


PRESETS: dict[str, ChannelSettings] = {
    name: ChannelSettings(**table) for name, table in _PRESET_TABLES.items()
}


def channel_settings(comm: Any) -> ChannelSettings | None:
    """What ``comm=`` resolves to: None (off), a preset, a settings object, or a mapping
    ``{"preset": name, field: value, ...}`` (a preset with fields replaced)."""
    if comm is None or (isinstance(comm, str) and comm.lower() in OFF):
        return None
    if isinstance(comm, ChannelSettings):
        return comm
    if isinstance(comm, str):
        if comm not in PRESETS:
            raise ValueError(f"comm: unknown preset {comm!r}; presets: {sorted(PRESETS)}, or 'off'")
        return PRESETS[comm]
    if isinstance(comm, Mapping):
        rest = dict(comm)
        base = channel_settings(rest.pop("preset", None)) or ChannelSettings()
        names = {f.name for f in fields(ChannelSettings)}
        unknown = sorted(set(rest) - names, key=str)
        if unknown:
            raise ValueError(f"comm: unknown field(s) {unknown}; fields: preset, {sorted(names)}")
        return replace(base, **rest)
    raise TypeError(
        f"comm must be None, 'off', a preset name {sorted(PRESETS)}, a ChannelSettings or a "
        f"mapping, got {comm!r}"
    )


def silent(actions: Any, settings: ChannelSettings, xp: Any = np) -> Any:
    """8-number actions (..., 8) padded with a silent message part: send flag -1, zeros."""
    pad = xp.zeros((*actions.shape[:-1], 1 + settings.message_dim), actions.dtype)
    pad[..., 0] = -1.0
    return xp.concatenate([actions, pad], axis=-1)


def _mix(x: Any) -> Any:
    """splitmix64's finalizer on uint64 arrays (wraps modulo 2^64)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


class Channel(NamespacePickled):
    """The channel's state over a batch of k environments of n robots (docs/channel.md).

    Arrays have the environment index first (k = 1 for one environment); ``ids`` are the
    core's (``...`` for one environment)."""

    def __init__(
        self,
        settings: ChannelSettings,
        xp: Any,
        k: int,
        n: int,
        period: float,
        first_seeds: Sequence[int | None],
    ) -> None:
        self.settings = s = settings
        self.xp, self.k, self.n, self.period = xp, k, n, period
        self.per_period, self.slot_periods = s.schedule(period)
        self.per_period = min(self.per_period, n)
        self.ring = s.max_delay(period) + 1  # deliveries are at most ring - 1 periods away
        d, m, r = s.message_dim, s.inbox_size, self.ring
        self.rngs = [self._generator(seed) for seed in first_seeds]
        self.key = xp.zeros(k, np.uint64)
        # messages carry the step that wrote them in column 0 (exact in float64), where
        # the action has its send flag: a written message is the quantized part, time first
        self.out_msg = xp.zeros((k, n, d + 1))
        self.out_full = xp.zeros((k, n), bool)
        # in flight: one row per (env, due % ring, to, from), and a spare one (never due)
        self._spare = cells = k * r * n * n
        self.fly_msg = xp.zeros((cells + 1, d + 1))
        self.fly_ok = xp.zeros(cells + 1, bool)
        self.in_msg = xp.zeros((k, n, m, d + 1))  # the inboxes
        self.in_ok = xp.zeros((k, n, m), bool)
        self.now = xp.zeros(k)  # the last step's index
        # constants: the TDMA table over one cycle, index arrays of the ring and the inbox
        cycle = self.slot_periods * n
        turn = (np.arange(cycle) // self.slot_periods) * self.per_period
        mine = (np.arange(n)[None, :] - turn[:, None]) % n < self.per_period
        self._speak = xp.asarray(mine & (np.arange(cycle) % self.slot_periods == 0)[:, None])
        self._other = xp.asarray(~np.eye(n, dtype=bool))
        cell = ((np.arange(k)[:, None, None] * r) * n + np.arange(n)[:, None]) * n + np.arange(n)
        self._cell = xp.asarray(cell)  # flat (env, due = 0, to, from) rows
        self._env_slot = xp.asarray(np.arange(k) * r)
        self._pair = xp.asarray(
            (np.arange(n)[:, None] * n + np.arange(n)[None, :]).astype(np.uint64)
        )
        # the first of each (env, robot)'s n + M merge candidates, as a flat row
        self._candidate = xp.asarray((np.arange(k * n) * (n + m)).reshape(k, n, 1))
        self._slots = xp.asarray(np.arange(1, m + 1)[:, None])  # inbox slot q holds valid no. q + 1

    @staticmethod
    def _generator(seed: int | None) -> np.random.Generator:
        return np.random.default_rng(None if seed is None else [_STREAM, int(seed)])

    def seed(self, rows: list[int], seeds: Sequence[int]) -> None:
        for i, seed in zip(rows, seeds, strict=True):
            self.rngs[i] = self._generator(seed)

    def reset(self, ids: Any, rows: list[int]) -> None:
        """Empty outboxes, air and inboxes of ``ids``; each takes its episode's key."""
        ids = slice(None) if ids is Ellipsis else ids
        keys = np.array([self.rngs[i].integers(2**63) for i in rows], np.uint64)
        self.key[ids] = self.xp.asarray(keys)
        self.out_full[ids] = False
        self.in_ok[ids] = False
        self.fly_ok[: self._spare].reshape(self.k, -1)[ids] = False

    def speaks(self, t: Any) -> Any:
        """(k, n) bool: robot j owns a slot at step t (k,)."""
        return self._speak[t % len(self._speak)]

    def step(self, t: Any, part: Any, positions: Any) -> None:
        """One period: ``part`` (k, n, 1 + D) the send flags and messages written with the
        actions of step ``t`` (k,), ``positions`` (k, n, 3) the vehicles' at sending."""
        xp, s, d = self.xp, self.settings, self.settings.message_dim
        self.now = t.astype(np.float64)  # the inbox's ages count from here
        write = part[..., 0] > 0
        if bool(write.any()):
            msg = s.quantize(part, xp)
            msg[..., 0] = self.now[:, None]
            self.out_msg = xp.where(write[..., None], msg, self.out_msg)
            self.out_full |= write
        tx = self.out_full if self.per_period >= self.n else self.speaks(t) & self.out_full
        if bool(tx.any()):
            self.out_full = self.out_full & ~tx
            self._send(t, tx, positions)
        if bool(self.fly_ok.any()):  # what is due now reaches the inboxes
            rows, n = self._env_slot + t % self.ring, self.n  # (env, due) of (k ring, to, from)
            flag = self.fly_ok[: self._spare].reshape(-1, n, n)
            got_ok = flag[rows]
            flag[rows] = False
            self._merge(got_ok, self.fly_msg[: self._spare].reshape(-1, n, n, d + 1)[rows])

    def _send(self, t: Any, tx: Any, positions: Any) -> None:
        xp, s = self.xp, self.settings
        d2 = positions[:, :, None, :] - positions[:, None, :, :]
        d2 = d2 * d2
        rng = xp.sqrt(d2[..., 0] + d2[..., 1] + d2[..., 2])  # (k, to, from); no 3-sum
        ok = tx[:, None, :] & self._other & (rng <= s.max_range_m)
        if s.loss_probability > 0 or not math.isinf(s.loss_range_m):
            ok &= self._uniform(t) >= s.loss(rng, xp)
        due = (t[:, None, None] + s.delay_periods(rng, self.period, xp)) % self.ring
        # one flat index (cheaper than four); what is not sent goes to the spare last row
        at = xp.where(ok, self._cell + due * (self.n * self.n), self._spare)
        self.fly_msg[at] = self.out_msg[:, None, :, :]
        self.fly_ok[at] = ok

    def _uniform(self, t: Any) -> Any:
        """(k, to, from) uniforms in [0, 1): a hash of (episode key, step, pair)."""
        n2 = np.uint64(self.n * self.n)
        count = t.astype(np.uint64)[:, None, None] * n2 + self._pair
        x = self.key[:, None, None] + count * np.uint64(0x9E3779B97F4A7C15)
        return (_mix(x) >> np.uint64(11)).astype(np.float64) * _U53

    def _merge(self, got_ok: Any, got_msg: Any) -> None:
        """The inbox keeps the M newest: this period's deliveries (sender order), then the
        older ones; expired ones leave."""
        xp = self.xp
        ok = xp.concatenate([got_ok, self.in_ok], axis=-1)
        msg = xp.concatenate([got_msg, self.in_msg], axis=-2)
        ok &= self.now[:, None, None] - msg[..., 0] <= self.settings.max_age_periods
        # the q-th valid candidate goes to slot q (a stable partition, no sort)
        rank = xp.cumsum(ok, axis=-1)  # (k, n, n + M): valid candidates up to each
        pick = ok[..., None, :] & (rank[..., None, :] == self._slots)  # (k, n, M, n + M)
        flat = msg.reshape(-1, msg.shape[-1])  # one flat index: cheaper than three
        self.in_msg = flat[self._candidate + xp.argmax(pick, axis=-1)]
        self.in_ok = rank[..., -1:] >= self._slots[:, 0]

    def block(self, ids: Any) -> Any:
        """(k', n, M (D + 2)) float32 inbox observations of ``ids`` (docs/channel.md)."""
        xp, s = self.xp, self.settings
        ids = slice(None) if ids is Ellipsis else ids
        vals = self.in_msg[ids]
        age = self.now[ids][:, None, None] - vals[..., 0]
        f = (self.in_ok[ids] & (age <= s.max_age_periods)).astype(np.float64)
        vals = vals * f[..., None]
        vals[..., 0] = age * (f * (1.0 / s.max_age_periods))
        out = xp.concatenate([vals[..., 1:], vals[..., :1], f[..., None]], axis=-1)
        out = out.astype(np.float32)
        return out.reshape(*out.shape[:-2], s.block_size)


def block_bounds(s: ChannelSettings) -> tuple[np.ndarray, np.ndarray]:
    """The inbox block's observation bounds: messages in [-1, 1], age and flag in [0, 1]."""
    low = np.tile(np.r_[-np.ones(s.message_dim), 0.0, 0.0], s.inbox_size).astype(np.float32)
    high = np.ones(s.block_size, np.float32)
    return low, high
