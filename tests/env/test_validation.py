"""Input validation and determinism of construction: every keyword option, reset seed and
action is checked against what is documented, and rejected with an error that names the
argument and states what is allowed; environments built the same way are the same."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_seed_test

import uvms_env
from uvms_env.env import CoopTransportEnv
from uvms_env.scenarios import make, replace
from uvms_env.scenarios.overrides import SCENARIO_OVERRIDES, validate_overrides

NAN, INF = math.nan, math.inf


@pytest.fixture(scope="module")
def paper_env(paper):
    env = CoopTransportEnv(paper)
    yield env
    env.close()


@pytest.fixture(scope="module")
def short_env():
    """Built from numpy scalars: they are accepted and normalized."""
    env = uvms_env.parallel_env(
        "short",
        seed=np.int64(1),
        max_cycles=np.int32(50),
        sensor_noise=np.float32(0.5),
        reseed_geometry=np.bool_(True),
    )
    yield env
    env.close()


def holding(env: CoopTransportEnv) -> dict[str, np.ndarray]:
    tau = env.sim.holding_inputs() / env.sim.tau_max
    return {a: tau[i].astype(np.float32) for i, a in enumerate(env.possible_agents)}


# -- constructor options: one schema for scenario overrides and environment options ------------
BAD_OPTIONS = [
    # (keyword arguments, error type, message: names the argument and what is allowed)
    ({"n_agents": 2.5}, TypeError, r"n_agents: expected int in 2\.\.8"),
    ({"n_agents": "3"}, TypeError, r"n_agents: expected int in 2\.\.8"),
    ({"n_agents": True}, TypeError, r"n_agents: expected int"),
    ({"max_cycles": 2.7}, TypeError, r"max_cycles: expected None or int >= 1"),
    ({"max_cycles": "10"}, TypeError, r"max_cycles: expected None or int >= 1"),
    ({"max_cycles": 0}, ValueError, r"max_cycles: expected None or int >= 1"),
    ({"sensor_noise": NAN}, ValueError, r"sensor_noise: expected finite float >= 0"),
    ({"sensor_noise": INF}, ValueError, r"sensor_noise: expected finite float >= 0"),
    ({"sensor_noise": "0.1"}, TypeError, r"sensor_noise: expected finite float >= 0"),
    ({"success_pos_tol": -1}, ValueError, r"success_pos_tol: expected finite float > 0"),
    ({"success_pos_tol": NAN}, ValueError, r"success_pos_tol: expected finite float > 0"),
    ({"success_att_tol": 0}, ValueError, r"success_att_tol: expected finite float > 0"),
    ({"reseed_geometry": "no"}, TypeError, r"reseed_geometry: expected bool"),
    ({"reseed_geometry": 1}, TypeError, r"reseed_geometry: expected bool"),
    ({"damping_scale": -1.0}, ValueError, r"damping_scale: expected finite float >= 0"),
    ({"damping_scale": INF}, ValueError, r"damping_scale: expected finite float >= 0"),
    ({"damping_scale": "1"}, TypeError, r"damping_scale: expected finite float >= 0"),
    ({"mismatch": 0.5}, ValueError, r"mismatch: expected finite float in \[0, 0\.5\)"),
    ({"mismatch": NAN}, ValueError, r"mismatch: expected finite float in \[0, 0\.5\)"),
    ({"mismatch": True}, TypeError, r"mismatch: expected finite float"),
    ({"substeps": 0}, ValueError, r"substeps: expected int >= 1"),
    ({"substeps": 4.0}, TypeError, r"substeps: expected int >= 1"),
    ({"max_steps": 0}, ValueError, r"max_steps: expected int >= 1"),
    ({"max_steps": "300"}, TypeError, r"max_steps: expected int >= 1"),
    ({"seed": -1}, ValueError, r"seed: expected None or int >= 0"),
    ({"seed": 1.5}, TypeError, r"seed: expected None or int >= 0"),
    ({"seed": True}, TypeError, r"seed: expected None or int >= 0"),
    ({"seed": "1"}, TypeError, r"seed: expected None or int >= 0"),
    ({"current": "hurricane"}, ValueError, r"current: expected one of 'none', 'mild', 'strong'"),
    ({"current": None}, TypeError, r"current: expected one of 'none', 'mild', 'strong'"),
    ({"internal_wrench_every": -1}, ValueError, r"internal_wrench_every: expected int >= 0"),
    ({"internal_wrench_every": 1.5}, TypeError, r"internal_wrench_every: expected int >= 0"),
    ({"constraint_mode": "ignore"}, ValueError, r"constraint_mode: .*'penalize', 'terminate'"),
    ({"constraint_mode": 0}, TypeError, r"constraint_mode: .*'penalize', 'terminate'"),
    ({"reward_weights": [("progress", 1.0)]}, TypeError, r"reward_weights: .*dict"),
    ({"reward_weights": {"progress": "1"}}, TypeError, r"reward_weights\['progress'\]"),
    ({"reward_weights": {"progress": NAN}}, ValueError, r"reward_weights\['progress'\]"),
    ({"reward_weights": {"progress": True}}, TypeError, r"reward_weights\['progress'\]"),
]


@pytest.mark.parametrize(("kwargs", "error", "message"), BAD_OPTIONS, ids=str)
def test_bad_constructor_option_raises_naming_it_and_the_allowed_values(kwargs, error, message):
    # validated before anything is built: cheap, and the same for every family
    with pytest.raises(error, match=message):
        uvms_env.parallel_env("short", **kwargs)


@pytest.mark.parametrize(("kwargs", "error", "message"), BAD_OPTIONS[:4], ids=str)
def test_options_on_a_built_scenario_go_through_the_same_schema(paper, kwargs, error, message):
    if "n_agents" in kwargs:
        message = "n_agents"  # never allowed on a built Scenario
        error = (TypeError, ValueError)
    with pytest.raises(error, match=message):
        CoopTransportEnv(paper, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [case for case in BAD_OPTIONS if next(iter(case[0])) in SCENARIO_OVERRIDES],
    ids=str,
)
def test_make_rejects_the_same_bad_overrides(kwargs, error, message):
    with pytest.raises(error, match=message):
        make("random", **kwargs)


def test_unknown_keywords_list_every_allowed_key_with_its_range(paper):
    with pytest.raises(ValueError, match=r"unknown option.*'colour'") as exc:
        uvms_env.parallel_env("short", colour="red")
    text = str(exc.value)
    for fragment in ("n_agents (int in 2..8)", "mismatch (finite float in [0, 0.5))",
                     "reseed_geometry (bool)", "max_cycles (None or int >= 1)"):  # fmt: skip
        assert fragment in text
    with pytest.raises(ValueError, match=r"unknown scenario override.*allowed: .*current"):
        make("paper", speed=3)


def test_random_family_n_agents_is_checked_against_its_range():
    with pytest.raises(ValueError, match=r"n_agents: expected int in 2\.\.8"):
        make("random", n_agents=9)
    with pytest.raises(ValueError, match="exactly 2 agents"):
        make("short", n_agents=3)


@pytest.mark.parametrize(
    ("change", "error", "message"),
    [
        ({"sensor_noise": NAN}, ValueError, "sensor_noise"),
        ({"sensor_noise": INF}, ValueError, "sensor_noise"),
        ({"success_pos_tol": NAN}, ValueError, "success_pos_tol"),
        ({"success_att_tol": 0.0}, ValueError, "success_att_tol"),
        ({"damping_scale": NAN}, ValueError, "damping_scale"),
        ({"max_steps": 2.5}, TypeError, "max_steps"),
        ({"seed": True}, TypeError, "seed"),
        ({"period": NAN}, ValueError, "period"),
    ],
    ids=str,
)
def test_scenario_fields_reject_nan_inf_and_wrong_types(paper, change, error, message):
    with pytest.raises(error, match=message):
        replace(paper, **change)


def test_numpy_scalars_are_accepted_and_normalized(short_env):
    out = validate_overrides({"seed": np.uint8(3), "mismatch": np.float32(0.25)})
    assert out == {"seed": 3, "mismatch": 0.25}
    assert type(out["seed"]) is int and type(out["mismatch"]) is float
    assert type(short_env.max_cycles) is int and short_env.max_cycles == 50
    assert short_env.reseed_geometry is True and short_env.scenario.seed == 1
    assert short_env.scenario.sensor_noise == 0.5


# -- reset seeds ---------------------------------------------------------------------------------
BAD_SEEDS = [
    (True, TypeError),
    (False, TypeError),
    (np.True_, TypeError),
    ([1, 2], TypeError),
    ("1", TypeError),
    (1.5, TypeError),
    (np.float64(1.0), TypeError),
    (-1, ValueError),
    (np.int64(-3), ValueError),
]


@pytest.mark.parametrize("family", ["paper", "short"])
@pytest.mark.parametrize(("seed", "error"), BAD_SEEDS, ids=repr)
def test_reset_rejects_seeds_that_are_not_non_negative_ints(
    paper_env, short_env, family, seed, error
):
    env = paper_env if family == "paper" else short_env
    with pytest.raises(error, match=r"seed: expected None or int >= 0"):
        env.reset(seed=seed)


def test_reset_accepts_python_and_numpy_integer_seeds(short_env):
    a, _ = short_env.reset(seed=3)
    b, _ = short_env.reset(seed=np.int64(3))
    c, _ = short_env.reset(seed=np.uint16(3))
    for agent in a:
        assert np.array_equal(a[agent], b[agent]) and np.array_equal(a[agent], c[agent])


# -- actions --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "bad",
    [
        np.full(8, 0.1 + 0.2j),  # the imaginary part was dropped
        [0.1 + 0j] * 8,
        ["1"] * 8,
        "1",
        np.array(["0.1"] * 8, dtype=object),
        np.array([0.1] * 8, dtype=object),
        np.zeros(8, dtype=bool),
        [True] * 8,
        [None] * 8,
    ],
    ids=lambda a: f"{type(a).__name__}-{np.asarray(a).dtype}",
)
def test_non_real_actions_raise_naming_the_agent(paper_env, bad):
    paper_env.reset(seed=0)
    good = holding(paper_env)
    with pytest.raises(ValueError, match=r"uvms_1.*not numeric.*allowed: float or int"):
        paper_env.step({**good, "uvms_1": bad})
    paper_env.step(good)  # the rejected step did not advance or break the episode


def test_real_actions_of_any_float_or_int_dtype_are_accepted(paper_env):
    def run(convert):
        paper_env.reset(seed=0)
        return paper_env.step({a: convert(v) for a, v in holding(paper_env).items()})[0]

    ref = run(lambda v: v)  # float32
    for convert in (lambda v: v.astype(np.float64), lambda v: [float(x) for x in v]):
        out = run(convert)
        assert all(np.array_equal(ref[a], out[a]) for a in ref)
    for dtype in (np.float16, np.int64, np.uint8):
        run(lambda v, dtype=dtype: np.zeros(8, dtype=dtype))


@pytest.mark.parametrize(
    "filtered, message",
    [
        (lambda c: c * np.nan, "NaN or inf"),
        (lambda c: c[:1], r"shape \(1, 8\)"),
        (lambda c: None, "shape NoneType"),
    ],
)
def test_a_command_filters_bad_commands_raise_before_the_simulator(paper_env, filtered, message):
    """The filter's commands reach the simulator without the adapter's check: they get
    their own, and the refused step leaves the episode as it was."""
    paper_env.reset(seed=0)
    paper_env.command_filter = lambda raw, commands, first: filtered(commands)
    state = paper_env.state().copy()
    with pytest.raises(ValueError, match=f"command filter must return finite.*{message}"):
        paper_env.step(holding(paper_env))
    assert np.array_equal(paper_env.state(), state)
    paper_env.command_filter = None
    paper_env.step(holding(paper_env))


# -- determinism of construction -------------------------------------------------------------
def test_random_family_defaults_to_two_agents_whatever_the_seed():
    assert make("random", seed=5).n_agents == 2
    a, b = make("random", seed=5), make("random", seed=5, n_agents=2)
    assert np.array_equal(a.initial_q, b.initial_q) and np.array_equal(a.waypoints, b.waypoints)


@pytest.mark.parametrize("family", ["random", "short"])
def test_envs_built_alike_and_reset_alike_are_identical(family):
    envs = [uvms_env.parallel_env(family), uvms_env.parallel_env(family)]
    assert envs[0].possible_agents == envs[1].possible_agents == ["uvms_0", "uvms_1"]
    obs = [env.reset(seed=11)[0] for env in envs]
    assert all(np.array_equal(obs[0][a], obs[1][a]) for a in obs[0])
    act = holding(envs[0])
    steps = [env.step(act) for env in envs]
    assert all(np.array_equal(steps[0][0][a], steps[1][0][a]) for a in obs[0])
    assert steps[0][1] == steps[1][1]


@pytest.mark.parametrize("family", ["random", "short"])
def test_pettingzoo_seed_test_passes_without_a_seed_at_construction(family):
    parallel_seed_test(lambda: uvms_env.parallel_env(family, sensor_noise=0.5), num_cycles=20)
