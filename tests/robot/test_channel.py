"""The acoustic channel (``comm=``): its settings and presets, quantization, TDMA, latency
and loss, the inbox, the single and the batched environment alike, locality with messages,
clear errors and the official API checks with the channel on. (Channel off, bit for bit:
``test_channel_episodes``.)"""

from __future__ import annotations

import copy
import math
import pickle
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

import uvms_env
from uvms_env.env import CoopTransportGymEnv
from uvms_env.robot.channel import (
    HEADER_BITS,
    PRESETS,
    SOUND_SPEED,
    Channel,
    ChannelSettings,
    channel_settings,
    silent,
)
from uvms_env.vector import VectorEnv

H = 0.12  # the scenarios' control period


def settings(**kw) -> ChannelSettings:
    return ChannelSettings(**{"message_dim": 2, "bits_per_value": 8, **kw})


def act(env, flags, messages, control=None):
    """Actions of every agent: ``control`` (N, 8) (zeros), send flags (N,), messages (N, D)."""
    n = env.n
    control = np.zeros((n, 8)) if control is None else control
    rows = np.concatenate([control, np.asarray(flags, float)[:, None], messages], axis=1)
    return {a: rows[i] for i, a in enumerate(env.possible_agents)}


def inbox(env, obs, agent):
    """(M, D + 2) inbox slots of ``agent``: message, scaled age, valid flag."""
    block = obs[agent][env.observation_structure["messages"]]
    return block.reshape(env.comm.inbox_size, env.comm.slot_size)


# -- settings and presets ----------------------------------------------------------------------
def test_presets_and_spellings():
    assert {"ideal", "micromodem_fsk", "atm900", "s2c_48_78"} <= set(PRESETS)
    ideal = PRESETS["ideal"]
    assert math.isinf(ideal.bit_rate_bps) and ideal.loss_probability == 0
    assert ideal.modem_latency_periods == 0 and not ideal.propagation_delay
    assert SOUND_SPEED == 1500.0
    assert channel_settings(None) is None and channel_settings("off") is None
    assert channel_settings("atm900") is PRESETS["atm900"]
    custom = channel_settings({"preset": "atm900", "message_dim": 2})
    assert custom.message_dim == 2 and custom.bit_rate_bps == PRESETS["atm900"].bit_rate_bps
    assert settings().packet_bits == 2 * 8 + HEADER_BITS


@pytest.mark.parametrize(
    ("comm", "error", "message"),
    [
        ("wifi", ValueError, "unknown preset 'wifi'"),
        ({"preset": "ideal", "baud": 3}, ValueError, r"unknown field\(s\) \['baud'\]"),
        (3, TypeError, "comm must be"),
        ({"message_dim": 0}, ValueError, "message_dim must lie in"),
        ({"message_dim": 2.5}, TypeError, "message_dim must be an int"),
        ({"bits_per_value": 40}, ValueError, "bits_per_value"),
        ({"bit_rate_bps": 0.0}, ValueError, "bit_rate_bps must be > 0"),
        ({"loss_probability": 1.5}, ValueError, "loss_probability"),
        ({"loss_probability": float("nan")}, ValueError, "loss_probability is NaN"),
        ({"max_range_m": float("inf")}, ValueError, "max_range_m"),
        ({"propagation_delay": 1}, TypeError, "propagation_delay"),
        # contradictions: every message would expire before it arrives
        ({"modem_latency_periods": 10, "max_age_periods": 5}, ValueError, "expire in flight"),
    ],
)
def test_bad_settings_raise_clear_errors(comm, error, message):
    with pytest.raises(error, match=message):
        channel_settings(comm)


def test_bad_comm_option_of_the_environments(paper):
    with pytest.raises(ValueError, match="unknown preset"):
        uvms_env.parallel_env(paper, comm="wifi")
    with pytest.raises(ValueError, match="expire in flight"):
        VectorEnv("paper", comm={"modem_latency_periods": 9, "max_age_periods": 3})


# -- the model, on the channel alone -----------------------------------------------------------
@pytest.mark.parametrize("bits", [1, 3, 8, 16])
def test_quantization_error_is_bounded(bits):
    s = settings(bits_per_value=bits)
    x = np.linspace(-1.3, 1.3, 2001)  # finer than 8 bits
    q = s.quantize(x)
    assert np.all(np.abs(q - np.clip(x, -1, 1)) <= 1.0 / (2**bits - 1) + 1e-12)
    assert q.min() == -1.0 and q.max() == 1.0
    if bits <= 8:  # every level reached
        assert len(np.unique(np.round(q, 12))) == 2**bits


def speakers(s: ChannelSettings, n: int, steps: int) -> np.ndarray:
    ch = Channel(s, np, 1, n, H, [0])
    return np.array([ch.speaks(np.array([t]))[0] for t in range(steps)])


@pytest.mark.parametrize("n", [2, 3, 5])
def test_tdma_round_robin_one_slot_per_period(n):
    s = settings(bit_rate_bps=300.0)  # 36 bits per period: one 32-bit packet
    assert s.schedule(H) == (1, 1)
    table = speakers(s, n, 4 * n)
    assert np.array_equal(table.sum(axis=1), np.ones(4 * n))  # one robot per period
    assert np.array_equal(table.argmax(axis=1), np.arange(4 * n) % n)  # by index
    assert np.array_equal(table.sum(axis=0), np.full(n, 4))  # each once per N periods


def test_tdma_slow_medium_slots_span_periods_and_fast_one_carries_several():
    slow = settings(bit_rate_bps=100.0)  # 12 bits per period: a 32-bit slot takes 3
    assert slow.schedule(H) == (1, 3)
    table = speakers(slow, 3, 18)
    assert [list(np.flatnonzero(row)) for row in table[::3]] == [[0], [1], [2], [0], [1], [2]]
    assert table.sum() == 6 and not table[1::3].any() and not table[2::3].any()
    fast = settings(bit_rate_bps=800.0)  # 96 bits: three packets per period
    table = speakers(fast, 5, 5)
    assert [list(np.flatnonzero(row)) for row in table] == [
        [0, 1, 2], [0, 3, 4], [1, 2, 3], [0, 1, 4], [2, 3, 4],
    ]  # fmt: skip
    assert np.array_equal(table.sum(axis=0), np.full(5, 3))
    assert speakers(PRESETS["ideal"], 6, 3).all()  # an unlimited rate: everyone, always


def test_larger_teams_speak_less_often():
    s = settings(bit_rate_bps=300.0)
    per_robot = [speakers(s, n, 60).sum(axis=0)[0] for n in (2, 3, 6)]
    assert per_robot == [30, 20, 10]


def run_channel(s, positions, steps=60, k=64, seed=0):
    """Every robot sends every step; returns the delivered (env, step, to, from) flags."""
    n = positions.shape[1]
    ch = Channel(s, np, k, n, H, [seed + i for i in range(k)])
    ch.reset(slice(None), list(range(k)))
    part = np.ones((k, n, 1 + s.message_dim))
    got = []
    for t in range(steps):
        before = ch.fly_ok[: ch._spare].sum()
        ch.step(np.full(k, t), part, np.broadcast_to(positions, (k, *positions.shape[1:])))
        got.append(ch.fly_ok[: ch._spare].sum() - before)
    return ch, np.array(got)


def test_loss_probability_one_delivers_nothing():
    s = settings(loss_probability=1.0, bit_rate_bps=math.inf)
    ch, sent = run_channel(s, np.zeros((1, 3, 3)) + np.arange(3)[:, None])
    assert sent.sum() == 0 and not ch.in_ok.any()


@pytest.mark.parametrize("p", [0.0, 0.3])
def test_losses_are_independent_with_the_set_probability(p):
    s = settings(loss_probability=p, bit_rate_bps=math.inf)
    k, n, steps = 64, 3, 60
    ch = Channel(s, np, k, n, H, list(range(k)))
    ch.reset(slice(None), list(range(k)))
    pos = np.zeros((k, n, 3)) + np.arange(n)[:, None]
    part = np.ones((k, n, 3))
    sent = 0
    for t in range(steps):
        ch.step(np.full(k, t), part, pos)
        sent += ch.in_ok[..., 0].sum()  # the newest slot: a delivery this step (delay 0)
        ch.in_ok[:] = False
    pairs = k * steps * n  # each receiver gets n - 1 per step; we count its newest
    delivered = sent / pairs
    expected = 1 - p**2  # the newest slot is empty only when both senders were lost
    assert abs(delivered - expected) < 0.02


def test_loss_grows_with_range_logistically():
    s = settings(loss_probability=0.1, loss_range_m=500.0, loss_width_m=50.0)
    p = s.loss(np.array([0.0, 500.0, 1000.0, 3000.0]))
    assert p[0] == pytest.approx(0.1, abs=1e-4) and p[1] == pytest.approx(0.55)
    assert p[2] == pytest.approx(1.0, abs=1e-4) and p[3] == 1.0  # beyond max_range_m
    fixed = settings(loss_probability=0.2).loss(np.array([0.0, 1500.0]))
    assert np.allclose(fixed, 0.2)


def test_delay_counts_modem_latency_transmission_and_propagation():
    s = settings(bit_rate_bps=200.0, modem_latency_periods=2)  # a packet takes 0.16 s
    r = np.array([0.0, 100.0, 300.0])
    expected = 2 + np.floor((32 / 200.0 + r / SOUND_SPEED) / H)
    assert np.array_equal(s.delay_periods(r, H), expected)  # 3, 4, 4
    assert np.array_equal(PRESETS["ideal"].delay_periods(r, H), [0, 0, 0])


# -- the environments --------------------------------------------------------------------------
def test_spaces_grow_by_the_message_and_the_inbox(paper):
    s = settings(inbox_size=3)
    env = uvms_env.parallel_env(paper, comm=s)
    assert env.action_space("uvms_0").shape == (8 + 1 + 2,)
    assert env.observation_space("uvms_0").shape == (79 + 3 * 4,)
    assert env.observation_structure["messages"] == slice(79, 79 + 12)
    assert env.action_space("uvms_0") is env.action_space("uvms_0")
    venv = VectorEnv("paper", num_envs=2, comm=s)
    assert venv.action_space.shape == (2, 2, 11)
    assert venv.observation_space.shape == (2, 2, 91)
    features = uvms_env.parallel_env(paper, comm=s, observation_mode="features")
    obs, _ = features.reset(seed=0)
    assert obs["uvms_0"].shape == features.observation_space("uvms_0").shape


def test_message_arrives_after_the_expected_delay_with_its_age(paper):
    s = settings(bit_rate_bps=2400.0, modem_latency_periods=3)
    env = uvms_env.parallel_env(paper, comm=s)
    env.reset(seed=0)
    hold = env.sim.holding_inputs() / env.sim.tau_max
    q = env.sim.state.q
    r = np.linalg.norm(q[0, :3] - q[1, :3])
    d = int(s.delay_periods(np.array(r), H))
    assert d == 3  # the robots are metres apart: the modem's latency alone
    msg = np.array([[0.5, -0.25], [0.0, 0.0]])
    obs, *_ = env.step(act(env, [1, -1], msg, hold))  # robot 0 speaks at step 0
    for t in range(1, d + 3):
        assert not inbox(env, obs, "uvms_0")[:, -1].any()  # nobody wrote to robot 0
        slot = inbox(env, obs, "uvms_1")[0]
        if t - 1 < d:
            assert slot[-1] == 0, t
        else:  # in the observation returned by step d, then a period older each step
            assert slot[-1] == 1 and np.allclose(slot[:2], s.quantize(msg[0]), atol=1e-6)
            assert slot[2] == pytest.approx((t - 1) / s.max_age_periods)
        obs, *_ = env.step(act(env, [-1, -1], np.zeros((2, 2)), hold))


def test_latest_message_wins_and_waits_for_its_slot(paper):
    s = settings(bit_rate_bps=100.0)  # slots of 3 periods: robot 1 speaks at step 3
    env = uvms_env.parallel_env(paper, comm=s)
    env.reset(seed=0)
    hold = env.sim.holding_inputs() / env.sim.tau_max
    for t in range(4):
        msg = np.array([[0.0, 0.0], [0.1 * t, 0.5]])
        obs, *_ = env.step(act(env, [-1, 1 if t < 2 else -1], msg, hold))
    d = int(s.delay_periods(np.array(3.0), H))
    for _ in range(d):
        obs, *_ = env.step(act(env, [-1, -1], np.zeros((2, 2)), hold))
    slots = inbox(env, obs, "uvms_0")
    assert slots[0, -1] == 1 and slots[1:, -1].sum() == 0  # one message: the held one
    assert slots[0, 0] == pytest.approx(float(s.quantize(0.1)), abs=1e-6)  # written at 1
    assert slots[0, 2] == pytest.approx((3 + d - 1) / s.max_age_periods)  # its age: since 1


def test_silence_is_not_a_zero_message(paper):
    env = uvms_env.parallel_env(paper, comm="ideal")
    env.reset(seed=0)
    obs, *_ = env.step(act(env, [1, -1], np.zeros((2, 4))))
    assert inbox(env, obs, "uvms_1")[0, -1] == 1  # a zero message, received
    assert inbox(env, obs, "uvms_0")[:, -1].sum() == 0  # silence: nothing
    padded = silent(np.zeros((2, 8)), env.comm)
    assert padded.shape == (2, 13) and np.all(padded[:, 8] == -1) and not padded[:, 9:].any()


def test_inbox_keeps_the_newest_m_and_forgets_old_ones():
    s = settings(bit_rate_bps=math.inf, inbox_size=2, max_age_periods=5, propagation_delay=False)
    ch = Channel(s, np, 1, 3, H, [0])
    ch.reset(slice(None), [0])
    pos = np.zeros((1, 3, 3))
    for t in range(3):  # robot 1 speaks at steps 0 and 1, robot 2 at step 2
        flags = [-1, 1 if t < 2 else -1, 1 if t == 2 else -1]
        msg = [[0, 0], [0.1 * (t + 1), 0], [-0.5, 0]]
        ch.step(np.array([t]), np.c_[flags, msg][None], pos)
    slots = ch.block(...)[0, 0].reshape(2, 4)  # robot 0's
    assert np.allclose(slots[:, 0], s.quantize(np.array([-0.5, 0.2])), atol=1e-6)
    assert np.allclose(slots[:, 2], [0, 1 / 5]) and np.all(slots[:, 3] == 1)
    for t in range(3, 9):
        ch.step(np.array([t]), np.zeros((1, 3, 3)) - 1, pos)
    assert not ch.block(...).any()  # older than max_age_periods: gone


@pytest.mark.parametrize("comm", ["atm900", {"preset": "s2c_48_78", "loss_probability": 0.4}])
def test_single_and_vector_envs_deliver_the_same_messages(comm):
    """Same seed, same actions: the same observations, message blocks included, through
    automatic resets (each episode's losses from the channel's own seeded generator, the
    sensors' noise from the episode's). With noise: the kernels of the other noisy
    three-robot tests (tests/robot/test_channel_episodes.py), not two more compiled."""
    k, n, steps = 2, 3, 30
    kw = {"n_agents": n, "comm": comm, "max_cycles": 11, "sensor_noise": 1.0}
    venv = VectorEnv("random", num_envs=k, **kw)
    singles = [uvms_env.parallel_env("random", **kw) for _ in range(k)]
    vobs, _ = venv.reset(seed=5)
    obs = [e.reset(seed=5 + i)[0] for i, e in enumerate(singles)]
    size = venv.single_action_space.shape[0]
    rng = np.random.default_rng(0)
    received = 0
    for _ in range(steps):
        for i, e in enumerate(singles):  # the physics to rounding, the messages exactly
            one = np.stack([obs[i][a] for a in e.possible_agents])
            assert np.allclose(one[:, :79], vobs[i][:, :79], rtol=1e-6, atol=1e-6)
            assert np.array_equal(one[:, 79:], vobs[i][:, 79:])
        a = rng.uniform(-0.2, 0.2, (k, n, size))
        a[..., 8] = rng.choice([-1.0, 1.0], (k, n))
        vobs, *_ = venv.step(a)
        for i, e in enumerate(singles):
            o, _, term, trunc, _ = e.step({ag: a[i, j] for j, ag in enumerate(e.possible_agents)})
            obs[i] = e.reset()[0] if term["uvms_0"] or trunc["uvms_0"] else o
        received += vobs[..., venv.observation_structure["messages"]][..., 5::6].sum()
    assert received > 0


def test_same_seed_same_losses_and_new_seed_new_ones(paper):
    comm = {"preset": "ideal", "loss_probability": 0.5}

    def deliveries(seed):
        env = uvms_env.parallel_env(paper, comm=comm)
        env.reset(seed=seed)
        out = []
        for t in range(20):
            obs, *_ = env.step(act(env, [1, 1], np.full((2, 4), 0.01 * t)))
            out.append(inbox(env, obs, "uvms_0")[0].copy())
        return np.array(out)

    assert np.array_equal(deliveries(3), deliveries(3))
    assert not np.array_equal(deliveries(3), deliveries(4))


def test_channel_draws_nothing_from_the_physics_generators(paper):
    """The same seed gives the same physics with the channel on as off."""
    kw = {"sensor_noise": 1.0, "mismatch": 0.1, "current": "mild"}
    off = uvms_env.parallel_env(paper, **kw)
    on = uvms_env.parallel_env(paper, comm={"preset": "ideal", "loss_probability": 0.5}, **kw)
    a, b = off.reset(seed=2)[0], on.reset(seed=2)[0]
    rng = np.random.default_rng(0)
    for _ in range(5):
        assert np.array_equal(a["uvms_1"], b["uvms_1"][:79])
        u = rng.uniform(-0.3, 0.3, (2, 8))
        a = off.step({ag: u[i] for i, ag in enumerate(off.possible_agents)})[0]
        b = on.step(act(on, [1, 1], np.full((2, 4), 0.5), u))[0]


@pytest.mark.parametrize("family", ["paper", "random"])
def test_observations_are_local_with_the_channel(family, paper):
    """With the channel on, robot i's observation depends on robot j only through what j
    sent and the channel delivered: two global states that differ only in robot j give
    every other robot the same observation, messages included; a different message of j
    changes only the message blocks of the others."""
    scenario = (
        paper if family == "paper" else uvms_env.parallel_env("random", n_agents=3, seed=4).scenario
    )
    e = uvms_env.parallel_env(scenario, comm="ideal", sensor_noise=1.0)
    n, d = e.n, e.comm.message_dim
    msgs = np.linspace(-0.8, 0.8, n * d).reshape(n, d)

    def run(qq=None, zz=None, messages=msgs):
        e.reset(seed=3)
        e.step(act(e, np.ones(n), messages))
        if qq is not None:
            st = e.sim.state
            e.sim.set_state(qq, zz, st.x_O.copy(), st.v_O.copy())
        return e.observe()

    base = run()
    st = e.sim.state
    e.reset(seed=3)
    e.step(act(e, np.ones(n), msgs))
    st = e.sim.state
    q, zeta = st.q.copy(), st.zeta.copy()
    ref = run(q, zeta)
    for j in range(n):
        q2, zeta2 = q.copy(), zeta.copy()
        q2[j] += np.linspace(0.05, 0.3, 10)
        zeta2[j] += np.linspace(-0.2, 0.2, 10)
        moved = run(q2, zeta2)
        for i, agent in enumerate(e.possible_agents):
            assert np.array_equal(ref[agent], moved[agent]) == (i != j), (i, j)
        other = msgs.copy()
        other[j] = -other[j]
        told = run(messages=other)
        box = e.observation_structure["messages"]
        for i, agent in enumerate(e.possible_agents):
            assert np.array_equal(base[agent][:79], told[agent][:79])
            assert np.array_equal(base[agent][box], told[agent][box]) == (i == j), (i, j)


# -- errors ------------------------------------------------------------------------------------
def test_bad_actions_with_the_channel_name_the_agent(paper):
    env = uvms_env.parallel_env(paper, comm="atm900")
    env.reset(seed=0)
    good = act(env, [1, 1], np.zeros((2, 4)))
    with pytest.raises(ValueError, match=r"uvms_0.*shape \(13,\), got \(8,\).*channel is on"):
        env.step({a: np.zeros(8) for a in env.possible_agents})
    with pytest.raises(ValueError, match=r"uvms_1.*shape \(13,\), got \(12,\)"):
        env.step({**good, "uvms_1": np.zeros(12)})
    bad = good["uvms_1"].copy()
    bad[10] = np.nan
    with pytest.raises(ValueError, match="message of agent 'uvms_1' contains NaN"):
        env.step({**good, "uvms_1": bad})
    venv = VectorEnv("paper", num_envs=2, comm="atm900")
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 2, 13\).*channel is on"):
        venv.step(np.zeros((2, 2, 8)))
    a = np.zeros((2, 2, 13))
    a[1, 0, 12] = np.inf
    with pytest.raises(ValueError, match="message of environment 1, agent 'uvms_0'"):
        venv.step(a)


# -- the official checks and copies --------------------------------------------------------------
def test_parallel_api_with_the_channel(paper):
    parallel_api_test(uvms_env.parallel_env(paper, comm="atm900"), num_cycles=60)


def test_gymnasium_view_with_the_channel_passes_check_env(paper):
    env = CoopTransportGymEnv(paper, comm="s2c_48_78")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env, skip_render_check=True)
    assert env.action_space.shape == (2 * 13,) and env.observation_space.shape == (2 * 103,)


def test_torchrl_view_with_the_channel_passes_check_env_specs():
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from uvms_env.vector.torchrl_env import GROUP, CoopTransportTorchRLEnv

    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=3, max_cycles=4, comm="atm900"))
    check_env_specs(env)
    assert env.action_spec[GROUP, "action"].shape == (3, 2, 13)
    assert env.reset()[GROUP, "observation"].shape == (3, 2, 103)


def test_copies_continue_the_same_channel(paper):
    env = uvms_env.parallel_env(paper, comm={"preset": "atm900", "loss_probability": 0.5})
    env.reset(seed=1)
    for t in range(3):
        env.step(act(env, [1, 1], np.full((2, 4), 0.1 * t)))
    twin = pickle.loads(pickle.dumps(env))
    other = copy.deepcopy(env)
    a = act(env, [1, 1], np.full((2, 4), 0.7))
    for _ in range(8):
        o1, o2, o3 = env.step(a)[0], twin.step(a)[0], other.step(a)[0]
        assert np.array_equal(o1["uvms_0"], o2["uvms_0"]) and np.array_equal(
            o1["uvms_1"], o3["uvms_1"]
        )
