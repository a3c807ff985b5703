"""The talking expert (``nmpc:comm``, ``nmpc_expert.comm``).

* nothing arrives (every delivery lost): its 8 inputs are the silent expert's, bit for bit;
* its messages lie in [-1, 1] and carry what the docs say: decoded from a teammate's
  inbox, the world-frame disturbance estimate of the sender within the quantization bound,
  and the sender's index;
* the fused estimate is the documented weighted mean;
* without a channel, or with too small messages, it refuses clearly.
"""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from baselines.loaders.sources import PolicySource
from nmpc_expert.comm import (
    FRESH_PERIODS,
    MESSAGE_NUMBERS,
    STALE_PERIODS,
    TalkingNMPCPolicy,
    age_weight,
    attitude,
    decode_message,
    decode_sender,
    encode_message,
)
from uvms_env.episode import Step, play
from uvms_env.policy import AgentSpec
from uvms_env.robot.channel import ChannelSettings, channel_settings

KEYWORDS = {"n_agents": 3, "current": "mild", "mismatch": 0.1, "max_cycles": 40}
SEED = 11


def _inputs(policy: str, comm: object) -> np.ndarray:
    env = uvms_env.parallel_env("random", comm=comm, **KEYWORDS)
    out: list[np.ndarray] = []

    def record(step: Step) -> None:
        out.append(np.stack([step.actions[a][:8] for a in env.possible_agents]))

    play(env, PolicySource.parse(policy).factory(SEED), seed=SEED, on_step=record)
    return np.stack(out)


def test_silent_when_nothing_arrives() -> None:
    """Every delivery lost: the talking expert decides exactly as the silent one."""
    lost = {"preset": "ideal", "loss_probability": 1.0}
    talking = _inputs("nmpc:comm", lost)
    silent = _inputs("nmpc", lost)
    assert talking.shape == silent.shape and len(talking) == KEYWORDS["max_cycles"]
    np.testing.assert_array_equal(talking, silent)
    # and messages that do arrive change the decision (the test above is not vacuous)
    assert not np.array_equal(_inputs("nmpc:comm", "ideal"), silent)


def test_messages_carry_the_estimate() -> None:
    """8-bit messages without delay: each inbox holds the teammates' world-frame estimates
    of this period, within the quantization bound, with their senders' indices."""
    comm = {"preset": "ideal", "bits_per_value": 8}
    settings = channel_settings(comm)
    assert settings is not None
    env = uvms_env.parallel_env("random", comm=comm, **KEYWORDS)
    agents = env.possible_agents
    checked = 0

    def check(step: Step) -> None:
        nonlocal checked
        sent = {}
        for i, a in enumerate(agents):
            p = step.policies[a]
            assert isinstance(p, TalkingNMPCPolicy)
            m = step.actions[a][9:]
            assert step.actions[a][8] > 0 and np.all(np.abs(m) <= 1.0)
            truth = attitude(p._x0[:6]) @ p.disturbance[:3]
            sent[i] = (truth, p.scale)
        bound = 1.0 / ((1 << settings.bits_per_value) - 1) + 1e-6
        for j, a in enumerate(agents):
            slots = step.observations[a][-settings.block_size :].reshape(
                settings.inbox_size, settings.slot_size
            )
            for slot in slots:
                if slot[settings.message_dim + 1] < 0.5 or slot[settings.message_dim] > 0:
                    continue  # empty, or last period's
                sender = decode_sender(slot[: settings.message_dim])
                assert sender is not None and sender != j
                truth, scale = sent[sender]
                if np.all(np.abs(truth) < scale):  # not clipped
                    got = decode_message(slot[: settings.message_dim], scale)
                    np.testing.assert_array_less(np.abs(got - truth), bound * scale)
                    checked += 1

    play(env, PolicySource.parse("nmpc:comm").factory(SEED), seed=SEED, on_step=check)
    assert checked >= (len(agents) - 1) * len(agents) * (KEYWORDS["max_cycles"] - 5)


def test_encoding_round_trip() -> None:
    d = np.array([0.05, -0.2, 0.01])
    m = encode_message(d, 0.1, 4, sender=5)
    assert np.all(np.abs(m) <= 1) and m[0] == 0.5 and m[1] == -1.0  # clipped
    assert decode_sender(m) == 5 and decode_sender(m[:MESSAGE_NUMBERS]) is None
    np.testing.assert_allclose(decode_message(m, 0.1), [0.05, -0.1, 0.01])


def test_age_weight() -> None:
    w = age_weight(
        np.array([0, FRESH_PERIODS, (FRESH_PERIODS + STALE_PERIODS) / 2, STALE_PERIODS, 99])
    )
    np.testing.assert_allclose(w, [1, 1, 0.5, 0, 0])


def _spec(comm: ChannelSettings | None) -> AgentSpec:
    env = uvms_env.parallel_env("random", n_agents=3)
    env.reset(seed=SEED)
    return AgentSpec.from_scenario(env.scenario, 0, comm)


def test_fusion_is_the_weighted_mean() -> None:
    """A synthetic inbox: two fresh teammates, one duplicate of a sender (older, dropped),
    one stale message (ignored); the fused body-frame estimate is R^T of the mean."""
    comm = channel_settings("ideal")
    assert comm is not None
    p = TalkingNMPCPolicy(_spec(comm))
    p.reset()
    p._x0[3:6] = [0.1, -0.05, 0.7]
    p.disturbance[:3] = [0.01, 0.02, -0.01]
    rot = attitude(p._x0[:6])
    msgs = [
        (np.array([0.03, 0.0, 0.0]), 1, 0),
        (np.array([0.0, -0.03, 0.01]), 2, 1),
        (np.array([0.09, 0.09, 0.09]), 1, 3),  # sender 1 again, older: dropped
        (np.array([-0.09, 0.0, 0.0]), 2, STALE_PERIODS + 1),  # stale
    ]
    inbox = np.zeros((comm.inbox_size, comm.slot_size))
    for k, (d, sender, age) in enumerate(msgs):
        inbox[k, : comm.message_dim] = encode_message(d, p.scale, comm.message_dim, sender)
        inbox[k, comm.message_dim] = age / comm.max_age_periods
        inbox[k, comm.message_dim + 1] = 1.0
    p._read_inbox(inbox.ravel())
    fused = p._input_disturbance()
    own = rot @ p.disturbance[:3]
    mean = (own + msgs[0][0] + msgs[1][0]) / 3
    np.testing.assert_allclose(fused[:3], rot.T @ mean, atol=1e-12)
    np.testing.assert_array_equal(fused[3:], p.disturbance[3:])
    p.own_share = 1.0  # all of its own deviation from the mean: its own estimate
    np.testing.assert_allclose(p._input_disturbance(), p.disturbance, atol=1e-15)


def test_executed_takes_the_inputs_of_a_channel_action() -> None:
    """A driver that applies another action (DAgger) hands the full channel action back."""
    comm = channel_settings("ideal")
    assert comm is not None
    p = TalkingNMPCPolicy(_spec(comm))
    p.reset()
    action = np.linspace(-0.5, 0.5, comm.action_size)
    p.executed(action)
    np.testing.assert_array_equal(p._applied, action[:8])


def test_refuses_without_a_channel() -> None:
    with pytest.raises(ValueError, match="has none"):
        TalkingNMPCPolicy(_spec(None))
    with pytest.raises(ValueError, match="message_dim is 2"):
        TalkingNMPCPolicy(_spec(ChannelSettings(message_dim=2)))
    with pytest.raises(ValueError, match="observer"):
        PolicySource.parse("nmpc:comm,paper").factory(0)
    # an evaluation refuses it before any episode (a usage error naming the policy); one
    # that does not check first (a training run's) fails the episode with it recorded
    from baselines.evaluation.runner import UsageError, evaluate

    with pytest.raises(UsageError, match=r"nmpc:comm.*has none"):
        evaluate(["nmpc:comm"], ["paper"], 1, 0, 1, max_cycles=2, progress=False)
    rows = evaluate(["nmpc:comm"], ["paper"], 1, 0, 1, max_cycles=2, progress=False, check=False)
    assert "has none" in rows[0]["error"]
