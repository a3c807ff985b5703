"""The PettingZoo environment: API conformance, locality, determinism, constraints, reward,
episode end, rendering, registration."""

from __future__ import annotations

import json
import re
import tomllib
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pettingzoo
import pytest
from gymnasium.utils.env_checker import check_env
from nav_points import twist
from pettingzoo.test import parallel_api_test, parallel_seed_test

import uvms_env
from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.env import (
    CONSTRAINTS,
    ENV_ID,
    METRICS,
    OBSERVATION_FIELDS,
    OBSERVATION_SIZE,
    REWARD_TERMS,
    CoopTransportEnv,
    CoopTransportGymEnv,
    make_navigator,
    save_video,
)
from uvms_env.env.infos import end_name, episode_metrics, reward_terms
from uvms_env.env.registration import register_gymnasium
from uvms_env.navigation import Cylinder, Sphere
from uvms_env.robot.observation import FAR_OBSTACLE, NOISE_STD_Q, OBSERVATION_LAYOUT
from uvms_env.scenarios import replace
from uvms_env.sim.simulator import SimulationDiverged
from uvms_env.task.constraints import SAFETY_CONSTRAINTS
from uvms_env.task.team_kernel import CYLINDER_SLOTS, TeamKinematics

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def env(paper):
    e = CoopTransportEnv(paper)
    yield e
    e.close()


def holding(env: CoopTransportEnv) -> dict[str, np.ndarray]:
    tau = env.sim.holding_inputs() / env.sim.tau_max
    return {a: tau[i].astype(np.float32) for i, a in enumerate(env.possible_agents)}


def random_actions(env, rng, scale=1.0):
    return {a: (scale * rng.uniform(-1, 1, 8)).astype(np.float32) for a in env.possible_agents}


# -- official API tests ----------------------------------------------------------------------
def test_parallel_api(paper):
    env = CoopTransportEnv(paper)
    assert isinstance(env, pettingzoo.ParallelEnv)
    parallel_api_test(env, num_cycles=1000)
    env.max_cycles = 20  # the API test sets it as an attribute; the env must honour it
    env.reset(seed=0)
    for k in range(20):
        *_, trunc, _ = env.step(random_actions(env, np.random.default_rng(k), 0.2))
    assert trunc["uvms_0"] and not env.agents


def test_parallel_seed(paper):
    parallel_seed_test(
        lambda: CoopTransportEnv(paper, sensor_noise=1.0, current="mild", mismatch=0.1),
        num_cycles=50,
    )


def test_same_seed_same_actions_same_episode(paper):
    """Step-for-step replay over many steps with every random source on (the PettingZoo
    seed test compares one step only)."""
    kwargs = {"sensor_noise": 1.0, "current": "strong", "mismatch": 0.2}
    envs = [CoopTransportEnv(paper, **kwargs), CoopTransportEnv(paper, **kwargs)]
    rng = np.random.default_rng(7)
    actions = [random_actions(envs[0], rng, 0.5) for _ in range(150)]

    def play(env, seed):
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for act in actions:
            out.append(env.step(act))
        return out

    a, b = play(envs[0], 11), play(envs[1], 11)
    assert len(a) == len(b) == 151
    for x, y in zip(a, b, strict=True):
        assert _equal(x, y)
    again = play(envs[0], 11)  # reset(seed) on a used env replays too
    assert all(_equal(x, y) for x, y in zip(a, again, strict=True))
    other = play(envs[1], 12)
    assert not np.array_equal(a[1][0]["uvms_0"], other[1][0]["uvms_0"])  # noise differs


def _equal(x, y) -> bool:
    return json.dumps(_plain(x), sort_keys=True) == json.dumps(_plain(y), sort_keys=True)


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def test_gymnasium_view_passes_check_env(paper):
    env = CoopTransportGymEnv(paper)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")  # unbounded by nature
        check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (OBSERVATION_SIZE * 2,) and obs.dtype == np.float32
    obs, _, _, _, info = env.step(env.action_space.sample())
    assert set(reward_terms(info)) == set(REWARD_TERMS)
    assert set(info["agents"]) == {"uvms_0", "uvms_1"}
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(8))


# -- registration ------------------------------------------------------------------------------
def test_registered_with_pettingzoo_and_gymnasium():
    env = pettingzoo.make("parallel", ENV_ID, max_cycles=7)
    assert isinstance(env, CoopTransportEnv)  # native, not converted from AEC
    assert env.max_cycles == 7
    assert env.metadata["name"] == ENV_ID
    genv = gym.make(ENV_ID, max_cycles=3)
    assert isinstance(genv.unwrapped, CoopTransportGymEnv)
    genv.reset(seed=0)
    for _ in range(3):
        *_, term, trunc, _ = genv.step(genv.action_space.sample() * 0)
    assert trunc and not term
    register_gymnasium()  # registering again is a silent no-op


def test_gymnasium_1_registers_on_import_without_a_plugin_entry_point():
    """Gymnasium >= 1.0 (required) reads no ``gymnasium.envs`` plugin group: the id is
    registered by importing the package, which the module-prefixed id does itself."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "gymnasium>=1.0" in pyproject["project"]["dependencies"]
    assert "gymnasium.envs" not in pyproject["project"].get("entry-points", {})
    assert int(gym.__version__.split(".")[0]) >= 1
    genv = gym.make(f"uvms_env:{ENV_ID}", max_cycles=2)
    assert isinstance(genv.unwrapped, CoopTransportGymEnv)


def test_options_are_validated(paper):
    with pytest.raises(ValueError, match=r"allowed.*constraint_mode"):
        CoopTransportEnv(paper, colour="red")
    with pytest.raises(ValueError, match="constraint_mode"):
        CoopTransportEnv(paper, constraint_mode="ignore")
    with pytest.raises(ValueError, match="render_mode"):
        CoopTransportEnv(paper, render_mode="ascii")
    with pytest.raises(ValueError, match="max_cycles"):
        CoopTransportEnv(paper, max_cycles=0)
    with pytest.raises(ValueError, match="reward weight"):
        CoopTransportEnv(paper, reward_weights={"speed": 1.0})
    with pytest.raises(ValueError, match="n_agents"):
        uvms_env.parallel_env("paper", n_agents=3)


# -- spaces, layout, documentation -------------------------------------------------------------
def test_spaces_are_cached_and_layout_is_complete(env):
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
    assert env.action_space("uvms_0") is not env.action_space("uvms_1")  # seeded separately
    names = [f.name for f in OBSERVATION_FIELDS]
    assert names == [
        "q", "zeta", "object_pose", "object_twist", "waypoint", "goal", "nav_velocity",
        "obstacles", "load_share", "grasp_offset", "grasp_rotation", "time_fraction",
    ]  # fmt: skip
    assert list(env.observation_structure) == names
    covered = np.concatenate([np.arange(79)[s] for s in env.observation_structure.values()])
    assert np.array_equal(covered, np.arange(79)) and OBSERVATION_SIZE == 79
    assert env.observation_space("uvms_0").shape == (79,)
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("uvms_9")
    env.reset(seed=0)
    state = env.state()
    assert env.state_space.contains(state) and state.shape == (20 * 2 + 19,)


def test_docstring_observation_table_matches_structure():
    rows = re.findall(r"^\s*\| (\d+)(?:-(\d+))? \| `(\w+)`", CoopTransportEnv.__doc__, re.M)
    table = {name: slice(int(a), int(b or a) + 1) for a, b, name in rows}
    assert table == uvms_env.env.OBSERVATION_STRUCTURE


# -- observations --------------------------------------------------------------------------------
def test_observation_contents_at_start(env, paper):
    obs, _ = env.reset(seed=0)
    s = env.observation_structure
    nav = make_navigator(paper)
    for i, agent in enumerate(env.possible_agents):
        o = obs[agent].astype(float)
        assert np.allclose(o[s["q"]], paper.initial_q[i], atol=1e-6)
        assert np.allclose(o[s["object_pose"]], paper.object_start, atol=1e-6)
        assert np.allclose(o[s["waypoint"]], paper.waypoints[0])
        assert np.allclose(o[s["goal"]], paper.waypoints[-1])
        assert np.allclose(o[s["nav_velocity"]], twist(nav, paper.object_start, 0), atol=1e-6)
        assert np.allclose(o[s["grasp_offset"]], paper.grasp_offsets[i])
        assert np.allclose(o[s["grasp_rotation"]], paper.grasp_rotations[i].reshape(-1))
        assert o[s["load_share"]][0] == pytest.approx(0.5)
        obstacles = o[s["obstacles"]].reshape(3, 5)
        # nearest first; cylinders: dz = 0, flag 1
        dist = np.hypot(obstacles[:, 0], obstacles[:, 1]) - obstacles[:, 3]
        assert np.all(np.diff(dist) >= 0) and np.all(obstacles[:, [2]] == 0)
        assert np.all(obstacles[:, 4] == 1) and np.allclose(obstacles[:, 3], 0.6)
        assert o[s["time_fraction"]][0] == 0.0


def test_object_estimates_follow_the_true_object(env):
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(30):
        obs, *_ = env.step(random_actions(env, rng, 0.5))
    st, s = env.sim.state, env.observation_structure
    for agent in env.possible_agents:
        o = obs[agent].astype(float)
        assert np.allclose(o[s["object_pose"]], st.x_O, atol=1e-4)
        assert np.allclose(o[s["object_twist"]], st.v_O, atol=1e-4)
    assert np.abs(st.v_O).max() > 1e-3  # it did move


def test_obstacles_sorted_and_padded(paper):
    sphere = Sphere((3.0, 3.0, 2.0), 0.5)  # nearer than the cylinder
    scenario = replace(paper, obstacles=(Cylinder(4.0, -4.5, 0.6), sphere))
    env = CoopTransportEnv(scenario)
    obs, _ = env.reset(seed=0)
    block = obs["uvms_0"][env.observation_structure["obstacles"]].reshape(3, 5)
    start = paper.object_start
    assert np.allclose(block[0], [*(np.array(sphere.center) - start[:3]), 0.5, 0], atol=1e-5)
    assert np.allclose(block[1], [4.0 - start[0], -4.5 - start[1], 0, 0.6, 1], atol=1e-5)
    assert np.array_equal(block[2], np.array(FAR_OBSTACLE, dtype=np.float32))


def test_the_kernels_obstacle_slots_change_no_output(paper):
    """One kernel serves every scenario: the default slots (five of each kind, far-away
    stand-ins in the rows the scenario does not fill) give the same outputs, bit for bit,
    as a kernel with exactly the scenario's one cylinder and one sphere."""
    scenario = replace(paper, obstacles=(Cylinder(4.0, -4.5, 0.6), Sphere((3.0, 3.0, 2.0), 0.5)))
    env = CoopTransportEnv(scenario)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    env.step(random_actions(env, rng, 0.5))
    sim, n = env.sim, scenario.n_agents
    outputs = []
    for slots in (None, (1, 1)):
        kin = TeamKinematics(scenario, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE, slots)
        assert kin.cylinders.shape[0] == (CYLINDER_SLOTS if slots is None else 1)
        st = sim.state
        q, zeta = np.ascontiguousarray(st.q), np.ascontiguousarray(st.zeta)
        action = rng.uniform(-1, 1, (n, NU)) if not outputs else outputs[0][0]
        kin(action, q, zeta, q, zeta, np.ascontiguousarray(st.x_O), np.zeros((n, 2)), np.zeros(5))
        outputs.append([action] + [np.copy(o) for o in kin._call.outputs])
    for padded, exact in zip(outputs[0][1:], outputs[1][1:], strict=True):
        assert np.array_equal(padded, exact)


@pytest.mark.parametrize("mode", ["raw", "memory"])
@pytest.mark.parametrize("family", ["paper", "random"])
def test_observations_are_local(family, mode, paper):
    """Two global states that differ only in robot j give robot i the same observation
    (in the memory mode, after a few steps, the last command and the disturbance estimate
    included)."""
    if family == "paper":
        scenario = paper
    else:  # three robots around a ring, spheres and cylinders
        scenario = uvms_env.parallel_env("random", n_agents=3, seed=4).scenario
    for noise in (0.0, 1.0):
        e = CoopTransportEnv(scenario, sensor_noise=noise, observation_mode=mode)

        def start(e: CoopTransportEnv = e) -> None:  # same noise draws, a memory in use
            e.reset(seed=3)
            for k in range(3):
                e.step({a: np.full(NU, 0.1 * (k + 1)) for a in e.possible_agents})

        start()
        st = e.sim.state
        q, zeta, x_o, v_o = st.q.copy(), st.zeta.copy(), st.x_O.copy(), st.v_O.copy()
        for j in range(e.n):
            q2, zeta2 = q.copy(), zeta.copy()
            q2[j] += np.linspace(0.05, 0.3, 10)
            zeta2[j] += np.linspace(-0.2, 0.2, 10)
            views = []
            for qq, zz in ((q, zeta), (q2, zeta2)):
                start()
                e.sim.set_state(qq, zz, x_o, v_o)
                views.append(e.observe())
            for i, agent in enumerate(e.possible_agents):
                same = np.array_equal(views[0][agent], views[1][agent])
                assert same == (i != j), (noise, i, j)


def test_sensor_noise_perturbs_measurements_before_estimates(paper):
    env = CoopTransportEnv(paper, sensor_noise=1.0)
    obs, _ = env.reset(seed=0)
    s = env.observation_structure
    errors = np.array([obs[a][s["q"]] - paper.initial_q[i] for i, a in enumerate(obs)])
    ratio = np.abs(errors).mean(axis=0) / NOISE_STD_Q
    assert np.all(ratio > 0.01) and np.all(ratio < 4)
    pose = obs["uvms_0"][s["object_pose"]]
    assert 1e-4 < np.abs(pose[:3] - paper.object_start[:3]).max() < 0.3  # estimate is noisy


# -- actions -----------------------------------------------------------------------------------
def test_bad_actions_name_the_agent(env):
    env.reset(seed=0)
    good = holding(env)
    cases = [
        ({**good, "uvms_1": np.full(8, np.nan)}, "uvms_1.*NaN"),
        ({**good, "uvms_0": np.zeros(7)}, "uvms_0.*shape"),
        ({"uvms_0": good["uvms_0"]}, "no action for agent 'uvms_1'"),
        ({**good, "uvms_7": np.zeros(8)}, "unknown agent.*uvms_7"),
        ({**good, "uvms_0": ["a"] * 8}, "uvms_0.*not numeric"),
    ]
    for actions, message in cases:
        with pytest.raises(ValueError, match=message):
            env.step(actions)
    with pytest.raises(ValueError, match="dict"):
        env.step([good["uvms_0"], good["uvms_1"]])
    env.step(good)  # still usable


def test_actions_beyond_one_are_clipped_and_reported(env):
    env.reset(seed=0)
    act = holding(env)
    act["uvms_0"] = act["uvms_0"].copy()
    act["uvms_0"][0] = 3.0
    _, _, _, _, infos = env.step(act)
    assert infos["uvms_0"]["constraint_input"] == pytest.approx(2.0)
    assert infos["uvms_1"]["constraint_input"] < 0
    assert infos["uvms_0"]["cost"] >= 1


# -- constraints, reward, episode end -----------------------------------------------------------
def test_start_satisfies_every_constraint(env):
    env.reset(seed=0)
    values = env.constraint_values()
    for agent, g in values.items():
        assert list(g) == list(CONSTRAINTS)
        assert all(v <= 0 for v in g.values()), (agent, g)
        assert 3.0 < uvms_env.env.MANIPULABILITY_EPS - g["manipulability"] < 5.0  # ~4.2


def test_constraint_sign_convention_on_violating_states(env):
    env.reset(seed=0)
    st = env.sim.state
    q, zeta, x_o, v_o = st.q.copy(), st.zeta.copy(), st.x_O.copy(), st.v_O.copy()
    cases = [  # kind, robot, "q" or "zeta", component, value
        ("joint_limit", 1, "q", 7, 2.3),
        ("joint_speed", 0, "zeta", 8, -0.3),
        ("vehicle_speed", 1, "zeta", 5, 0.2),
        ("representation", 0, "q", 4, 1.45),
    ]
    for kind, robot, which, k, value in cases:
        q2, z2 = q.copy(), zeta.copy()
        (q2 if which == "q" else z2)[robot, k] = value
        env.sim.set_state(q2, z2, x_o, v_o)
        values = env.constraint_values()
        assert values[f"uvms_{robot}"][kind] > 0, kind
        assert values[f"uvms_{1 - robot}"][kind] <= 0, kind
    # the whole team moved into obstacle 0: collision for every robot (object included)
    shift = np.array([4.0, -4.5, 0.0]) - x_o[:3]
    q2, x2 = q.copy(), x_o.copy()
    q2[:, :3] += shift
    x2[:3] += shift
    env.sim.set_state(q2, zeta, x2, v_o)
    values = env.constraint_values()
    assert all(values[a]["collision"] > 0.5 for a in env.possible_agents)
    _, _, term, _, infos = env.step(holding(env))
    assert term["uvms_0"] and end_name(infos["uvms_0"]) == "collision"
    assert infos["uvms_0"]["violations_collision"] == 1
    assert infos["uvms_0"]["min_obstacle_clearance_m"] < 0
    # ending early never pays: the failure costs what every remaining period could cost,
    # every safety kind violated by every robot and every input saturated
    w, remaining = env.reward_weights, env.max_cycles - 1
    worst_period = w.violation * len(SAFETY_CONSTRAINTS) * env.n / env.n + w.effort * 1.0
    assert infos["uvms_0"]["reward_violation"] <= -(w.failure + remaining * worst_period)
    assert not env.agents
    v0 = CoopTransportEnv(env.scenario, reward_weights={"continuation": 0.0})
    assert v0.reward_weights.failure_penalty(remaining) == w.failure  # v0's one-off penalty


def test_reward_is_the_sum_of_its_terms_and_shared(env):
    env.reset(seed=0)
    rng = np.random.default_rng(2)
    total = 0.0
    for _ in range(100):
        _, rewards, _, _, infos = env.step(random_actions(env, rng))
        terms = reward_terms(infos["uvms_0"])
        assert list(terms) == list(REWARD_TERMS)
        assert rewards["uvms_0"] == sum(terms.values())
        assert rewards["uvms_0"] == rewards["uvms_1"]
        assert reward_terms(infos["uvms_1"]) == terms
        total += terms["violation"]
    assert total < 0  # random inputs break the 0.1 rad/s joint speed limit


def test_progress_rewards_motion_towards_the_waypoint(env, paper):
    env.reset(seed=0)
    st = env.sim.state
    q, x_o = st.q.copy(), st.x_O.copy()
    toward = paper.waypoints[0, :3] - x_o[:3]
    step = 0.1 * toward / np.linalg.norm(toward)
    q[:, :3] += step
    x_o[:3] += step
    env.sim.set_state(q, st.zeta, x_o, st.v_O)
    *_, infos = env.step(holding(env))
    assert infos["uvms_0"]["reward_progress"] == pytest.approx(
        env.reward_weights.progress * 0.1, abs=0.02
    )


def test_max_cycles_truncates(paper):
    env = CoopTransportEnv(paper, max_cycles=5)
    env.reset(seed=0)
    for k in range(5):
        obs, _, term, trunc, infos = env.step(holding(env))
        assert trunc["uvms_0"] == (k == 4) and not term["uvms_0"]
    assert obs["uvms_0"][env.observation_structure["time_fraction"]][0] == pytest.approx(1.0)
    metrics = episode_metrics(infos["uvms_0"])
    assert end_name(infos["uvms_0"]) == "max_cycles"
    assert list(metrics) == list(METRICS)
    assert [k.removeprefix("violations_") for k in METRICS if k.startswith("violations_")] == list(
        CONSTRAINTS
    )
    assert metrics["episode_steps"] == 5 and metrics["sim_time_s"] == pytest.approx(0.6)
    assert metrics["success"] is False and "policy_time_ms_median" not in metrics
    assert metrics["min_manipulability"] > 3.0 and metrics["grasp_drift_max_m"] < 1e-5
    assert metrics["internal_wrench_rms"] > 0 and metrics["control_effort"] > 0
    json.dumps(metrics, allow_nan=False)  # plain types
    with pytest.raises(RuntimeError, match="reset"):
        env.step(holding(env))
    assert CoopTransportEnv(paper).max_cycles == paper.max_steps
    quick = CoopTransportEnv(paper, max_cycles=2, internal_wrench_every=0)
    quick.reset(seed=0)
    quick.step(holding(quick))
    *_, infos = quick.step(holding(quick))
    assert np.isnan(infos["uvms_0"]["internal_wrench_rms"])


def test_terminate_mode_ends_on_any_violation(paper):
    env = CoopTransportEnv(paper, constraint_mode="terminate")
    env.reset(seed=0)
    _, _, term, _, infos = env.step({a: np.ones(8, np.float32) for a in env.agents})
    for _ in range(20):
        if term["uvms_0"]:
            break
        _, _, term, _, infos = env.step({a: np.ones(8, np.float32) for a in env.agents})
    assert term["uvms_0"] and end_name(infos["uvms_0"]) == "constraint"
    assert infos["uvms_0"]["reward_violation"] <= -env.reward_weights.failure


def test_success_ends_the_episode(paper):
    goal = paper.waypoints[-1]
    env = CoopTransportEnv(paper)
    env.reset(seed=0)
    st = env.sim.state
    q, x_o = st.q.copy(), st.x_O.copy()
    shift = goal[:3] - x_o[:3]
    q[:, :3] += shift
    x_o[:3] += shift
    env.sim.set_state(q, st.zeta, x_o, st.v_O)  # attitude error 0.07 rad < 0.1
    _, _, term, _, infos = env.step(holding(env))
    assert term["uvms_0"] and end_name(infos["uvms_0"]) == "success"
    assert infos["uvms_0"]["success"] is True
    assert infos["uvms_0"]["reward_success"] == env.reward_weights.success


def test_divergence_ends_the_episode_gracefully(env, monkeypatch):
    env.reset(seed=0)

    def boom(tau):
        raise SimulationDiverged("the simulation diverged (non-finite state)")

    monkeypatch.setattr(env.sim, "advance", boom)  # the engine's call into the simulator
    obs, _, term, _, infos = env.step(holding(env))
    assert term["uvms_0"] and end_name(infos["uvms_0"]) == "diverged"
    assert infos["uvms_0"]["diverged"] == 1
    assert env.diverged_reason == "the simulation diverged (non-finite state)"
    assert np.all(np.isfinite(obs["uvms_0"]))
    assert infos["uvms_0"]["success"] is False


def test_both_engines_implement_the_engine_protocol(env):
    """``EnvCore``'s engine interface is a ``typing.Protocol``: the scalar and the batched
    engine define every method of it with its parameters (none left to the stubs) and
    carry its attributes."""
    import inspect

    from uvms_env.env.core import Engine
    from uvms_env.env.scalar_engine import ScalarEngine
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.batched_engine import BatchedEngine

    inherited = ("steady", "features")  # host calls, unless an engine has device kernels
    methods = [m for m, f in vars(Engine).items() if inspect.isfunction(f) and m[0] != "_"]
    assert "step" in methods and set(inherited) <= set(methods)
    batched = VectorEnv("short", 2, threads=1)._core.engine
    for cls, engine in ((ScalarEngine, env._core.engine), (BatchedEngine, batched)):
        assert isinstance(engine, cls)
        for name in methods:
            method, stub = getattr(cls, name), getattr(Engine, name)
            assert method is not stub or name in inherited, (cls.__name__, name)
            params = list(inspect.signature(method).parameters)
            assert params == list(inspect.signature(stub).parameters), (cls.__name__, name)
        for attribute in Engine.__annotations__:
            assert hasattr(engine, attribute), (cls.__name__, attribute)


@pytest.mark.parametrize("every", [0, 1, 3])
def test_a_step_makes_one_compiled_call_for_the_physics_and_one_after_it(monkeypatch, every):
    """The period step, then the kinematics kernel (observations with the robots'
    sequencing and navigation twists, constraints, team rows, and the internal wrench
    inside wherever its metric is on)."""
    env = uvms_env.parallel_env("paper", internal_wrench_every=every, sensor_noise=1.0)
    env.reset(seed=0)
    names: list[str] = []
    call = BufferCall.__call__

    def counted(self, *args):
        names.append(self.fn.name())
        return call(self, *args)

    monkeypatch.setattr(BufferCall, "__call__", counted)
    for _ in range(4):
        names.clear()
        env.step({a: np.full(8, 0.2) for a in env.agents})
        assert len(names) == 2, names
        assert names[0].startswith("chain_step") and names[1].startswith("env_kernel")
        assert names[1].endswith("_chain_internal_wrench_n2") == (every > 0), names


def test_internal_wrench_matches_the_simulator(env):
    env.reset(seed=0)
    rng = np.random.default_rng(3)
    for _ in range(10):
        env.step({a: rng.uniform(-1, 1, 8) for a in env.agents})
    squeeze = env.sim.internal_wrench()  # the last period's inputs, at the state after it
    # independent: pseudo-inverse projection of the grasp wrenches onto null(G^T)
    lam = env.sim.wrenches().reshape(-1)
    g_t = env.sim.grasp_matrix_t()
    exact = (lam - np.linalg.pinv(g_t) @ (g_t @ lam)).reshape(-1, 6)
    assert np.allclose(squeeze, exact, atol=1e-9)
    # the metric's sample of the step (the kinematics kernel's): the same squeeze's norm
    sampled = env._core.engine.wrench_sq(np.bool_(True))
    assert sampled == pytest.approx(float(np.sum(exact**2)), rel=1e-9)


def test_the_wrench_metric_samples_every_kth_step():
    """``internal_wrench_every=3``: the kernel computes the wrench at every step, the
    metric is the RMS over the 3rd and 6th steps' squeezes, as the simulator's own
    projection gives them."""
    env = uvms_env.parallel_env("paper", internal_wrench_every=3, max_cycles=7)
    env.reset(seed=0)
    rng = np.random.default_rng(5)
    samples = []
    for t in range(1, 8):
        infos = env.step({a: rng.uniform(-0.5, 0.5, 8) for a in env.agents})[4]
        if t % 3 == 0:
            samples.append(float(np.sum(env.sim.internal_wrench() ** 2)))
    metrics = episode_metrics(infos[env.possible_agents[0]])
    assert len(samples) == 2 and not env.agents  # ended by the time limit
    assert metrics["internal_wrench_rms"] == pytest.approx(np.sqrt(np.mean(samples)), rel=1e-9)


# -- seeded geometry -----------------------------------------------------------------------------
def test_seeded_family_geometry_follows_reset_seed():
    env = uvms_env.parallel_env("short", seed=1)
    goal_1 = env.scenario.waypoints[-1].copy()
    env.reset(seed=2)
    goal_2 = env.scenario.waypoints[-1].copy()
    assert not np.allclose(goal_1, goal_2)
    world = env.sim
    env.reset()
    assert env.sim is world  # reset() keeps the geometry
    env.reset(seed=1)
    assert np.allclose(env.scenario.waypoints[-1], goal_1)
    env.reset(seed=2)
    assert env.sim is world  # cached: the same compiled objects
    fixed = uvms_env.parallel_env("short", seed=1, reseed_geometry=False, max_cycles=1)
    fixed.reset(seed=2)
    assert np.allclose(fixed.scenario.waypoints[-1], goal_1)
    *_, infos = fixed.step(holding(fixed))  # no obstacles at all:
    assert np.isnan(infos["uvms_0"]["min_obstacle_clearance_m"])
    assert infos["uvms_0"]["constraint_collision"] == -100.0


# -- rendering -----------------------------------------------------------------------------------
def test_rgb_array_rendering(paper, tmp_path):
    env = CoopTransportEnv(paper, render_mode="rgb_array")
    env.reset(seed=0)
    frames = [env.render()]
    for _ in range(3):
        env.step(holding(env))
        frames.append(env.render())
    frame = frames[-1]
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] > 100 and frame.shape[1] > 100 and frame.std() > 1
    gif = save_video(frames, tmp_path / "episode.gif")
    assert gif.stat().st_size > 1000
    env.close()


def test_mp4_needs_imageio(tmp_path, monkeypatch):
    """Without imageio an .mp4 is a clear ImportError naming it (a GIF still writes,
    through Pillow); with imageio and its ffmpeg plugin the video reads back frame by
    frame."""
    import builtins

    frames = [np.full((64, 64, 3), 40 * k, np.uint8) for k in range(3)]
    real_import = builtins.__import__

    def no_imageio(name, *args, **kwargs):
        if name.startswith("imageio"):
            raise ImportError(f"no module named {name!r}")
        return real_import(name, *args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(builtins, "__import__", no_imageio)
        with pytest.raises(ImportError, match="imageio"):
            save_video(frames, tmp_path / "a.mp4")
        assert save_video(frames, tmp_path / "a.gif").stat().st_size > 0
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    read = imageio.mimread(save_video(frames, tmp_path / "b.mp4"))
    assert len(read) == 3 and read[0].shape[:2] == (64, 64)
    assert read[2].mean() > read[0].mean() + 40  # the frames in their order


def test_human_rendering_is_headless_safe(paper, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = CoopTransportEnv(paper, render_mode="human")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="display"):
        assert env.render() is None
    env.close()
    plain = CoopTransportEnv(paper)
    plain.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert plain.render() is None


def test_v0_is_no_longer_registered_and_its_refusal_names_v1():
    """v1 changed the metrics and the infos: v0's numbers are not comparable."""
    assert ENV_ID == "uvms_env/CoopTransport-v1"
    with pytest.raises(gym.error.Error, match="v1"):
        gym.make("uvms_env/CoopTransport-v0")
    with pytest.raises(Exception, match="v1"):
        pettingzoo.make("parallel", "uvms_env/CoopTransport-v0")
