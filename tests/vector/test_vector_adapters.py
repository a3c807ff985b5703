"""The batched environment behind the two vector APIs: SB3's ``VecEnv`` (``VectorVecEnv``,
parameter sharing) and Gymnasium's ``VectorEnv`` (``CoopTransportVectorEnv``, centralized),
each checked against the single environments it batches, their API conventions and a
short training run."""

from __future__ import annotations

import importlib.util

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import uvms_env
from uvms_env.env.infos import end_code, end_name, episode_metrics
from uvms_env.env.registration import ENV_ID
from uvms_env.vector import VectorEnv
from uvms_env.vector.gym_vector import CoopTransportVectorEnv

needs_sb3 = pytest.mark.skipif(
    importlib.util.find_spec("stable_baselines3") is None, reason="stable-baselines3 not installed"
)
SEED = 7
OBS_ATOL = 1e-6  # float64 VectorEnv vs single envs: 1e-9 (its tests); observations are float32


def _vector(num_envs: int = 2, **kwargs) -> VectorEnv:
    kwargs.setdefault("dtype", "float64")
    if kwargs["dtype"] == "float32":  # as in training: spares CI a library build (~10 s)
        kwargs.setdefault("internal_wrench_every", 0)
    return VectorEnv("short", num_envs=num_envs, threads=1, **kwargs)


def _actions(rows: int, t: int, cols: int = 8) -> np.ndarray:
    return np.random.default_rng(t).uniform(-0.3, 0.3, (rows, cols)).astype(np.float32)


# -- SB3 ---------------------------------------------------------------------------------------
@needs_sb3
def test_sb3_matches_single_envs_through_truncation_and_auto_reset():
    from uvms_env.vector.sb3 import VectorVecEnv

    venv = VectorVecEnv(_vector(max_cycles=3), seed=SEED)
    n = venv.n_agents
    assert venv.num_envs == 2 * n and venv.agents == ["uvms_0", "uvms_1"]
    assert venv.seed() == [SEED, SEED, SEED + 1, SEED + 1]
    refs = [uvms_env.parallel_env(scenario="short", max_cycles=3) for _ in range(2)]
    ref_obs = [env.reset(seed=SEED + k)[0] for k, env in enumerate(refs)]
    obs = venv.reset()
    assert obs.shape == (4, 79) and obs.dtype == np.float32
    assert [info["episode_seed"] for info in venv.reset_infos] == [7, 7, 8, 8]
    for k in range(2):
        for a, agent in enumerate(venv.agents):
            np.testing.assert_allclose(obs[k * n + a], ref_obs[k][agent], atol=OBS_ATOL)
    for t in range(3):
        acts = _actions(venv.num_envs, t)
        obs, rewards, dones, infos = venv.step(acts)
        assert rewards.dtype == np.float32 and dones.dtype == bool and len(infos) == 4
        for k, env in enumerate(refs):
            step = {agent: acts[k * n + a] for a, agent in enumerate(venv.agents)}
            robs, rrew, rterm, rtrunc, rinfo = env.step(step)
            for a, agent in enumerate(venv.agents):
                i = k * n + a
                assert rewards[i] == pytest.approx(rrew[agent], abs=1e-6)
                assert dones[i] == (t == 2)
                assert infos[i]["cost"] == rinfo[agent]["cost"]
                if t < 2:
                    np.testing.assert_allclose(obs[i], robs[agent], atol=OBS_ATOL)
                    assert "terminal_observation" not in infos[i]
                else:
                    assert rtrunc[agent] and not rterm[agent]
                    np.testing.assert_allclose(
                        infos[i]["terminal_observation"], robs[agent], atol=OBS_ATOL
                    )
                    assert infos[i]["TimeLimit.truncated"] is True
                    assert infos[i]["episode_end"] == rinfo[agent]["episode_end"]
                    assert end_name(rinfo[agent]) == "max_cycles"
                    metrics = episode_metrics(rinfo[agent])
                    assert {k: infos[i][k] for k in metrics} == pytest.approx(metrics, nan_ok=True)
    for k, env in enumerate(refs):  # auto-reset: the single env's next reset()
        new, _ = env.reset()
        for a, agent in enumerate(venv.agents):
            np.testing.assert_allclose(obs[k * n + a], new[agent], atol=OBS_ATOL)
    venv.close()


@needs_sb3
def test_sb3_vecenv_contract():
    from stable_baselines3.common.vec_env import VecCheckNan, VecMonitor

    from uvms_env.vector.sb3 import VectorVecEnv

    venv = VectorVecEnv(_vector(3, dtype="float32", max_cycles=4))
    assert venv.observation_space == venv.vector_env.single_observation_space
    assert venv.action_space.shape == (8,) and venv.render_mode is None
    checked = VecCheckNan(venv, raise_exception=True)
    obs = checked.reset()
    assert obs.shape == (6, 79) and all(venv.observation_space.contains(o) for o in obs)
    for t in range(4):
        obs, rewards, dones, infos = checked.step(_actions(6, t))
        assert obs.shape == (6, 79) and rewards.shape == dones.shape == (6,)
        assert all(venv.observation_space.contains(o) for o in obs)
        assert len({id(info) for info in infos}) == 6  # one dict each: SB3 may mutate them
    assert dones.all() and all(
        venv.observation_space.contains(i["terminal_observation"]) for i in infos
    )
    assert venv.last_infos["constraint_values"].shape == (3, 2, 8)
    assert venv.get_attr("max_cycles") == [4] * 6 and venv.get_attr("n", [0, 5]) == [2, 2]
    venv.set_attr("max_cycles", 5)
    assert venv.vector_env.max_cycles == 5
    assert venv.env_method("state", indices=[1])[0].shape == (3, 20 * 2 + 19)
    assert venv.env_is_wrapped(VecMonitor) == [False] * 6
    with pytest.raises(RuntimeError, match="step_async"):
        venv.step_wait()
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros((5, 8), np.float32))
    # seed(s): the next reset starts environment k with seed s + k
    assert venv.seed(20) == [20, 20, 21, 21, 22, 22]
    fresh = VectorVecEnv(_vector(3, dtype="float32"), seed=20)
    np.testing.assert_array_equal(venv.reset(), fresh.reset())
    assert venv.seed() == [None] * 6  # used by that reset


@needs_sb3
def test_sb3_termination_is_not_truncation():
    from uvms_env.vector.sb3 import VectorVecEnv

    # Saturated inputs soon break a speed limit: "terminate" mode ends the episode there,
    # long before the time limit.
    venv = VectorVecEnv(_vector(1, constraint_mode="terminate", max_cycles=50), seed=SEED)
    venv.reset()
    for _ in range(40):
        _, _, dones, infos = venv.step(np.full((venv.num_envs, 8), 1.0, np.float32))
        if dones.any():
            break
    assert dones.all()
    for info in infos:
        assert info["TimeLimit.truncated"] is False
        assert end_name(info) == "constraint"
        assert info["terminal_observation"].shape == venv.observation_space.shape
        assert info["success"] is False and info["violation_periods"] >= 1


@needs_sb3
def test_sb3_ppo_learns_through_monitor_and_normalize():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from uvms_env.vector.sb3 import VectorVecEnv

    vector = _vector(2, dtype="float32", max_cycles=20, geometry_pool=4)
    venv = VecNormalize(VecMonitor(VectorVecEnv(vector)), clip_obs=10.0)
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=32,
        batch_size=64,
        n_epochs=1,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [8, 8]},
    )
    model.learn(total_timesteps=256)
    assert model.num_timesteps == 256
    # 64 team steps of 20: 3 episodes per env, 2 robots each, through VecMonitor
    assert len(model.ep_info_buffer) == 12
    assert {e["l"] for e in model.ep_info_buffer} == {20}
    assert {s.seed for s in vector.scenarios} <= set(range(4))  # the geometry pool's seeds
    venv.close()


# -- Gymnasium -----------------------------------------------------------------------------------
def _gym(num_envs: int = 2, **kwargs) -> CoopTransportVectorEnv:
    kwargs = {"scenario": "short", "dtype": "float64", "threads": 1, "max_cycles": 3, **kwargs}
    env = gymnasium.make_vec(ENV_ID, num_envs=num_envs, **kwargs)
    assert isinstance(env, CoopTransportVectorEnv)
    return env


def test_make_vec_builds_the_batched_env_with_its_kwargs():
    env = gymnasium.make_vec(
        ENV_ID,
        num_envs=3,
        vectorization_mode="vector_entry_point",
        scenario="short",
        dtype="float32",
        threads=1,
        max_cycles=5,
        internal_wrench_every=0,
    )
    assert isinstance(env, CoopTransportVectorEnv) and env.num_envs == 3
    inner = env.unwrapped.vector_env
    assert (inner.dtype, inner.threads, inner.max_cycles, inner.family) == (
        "float32",
        1,
        5,
        "short",
    )
    assert env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert env.spec is not None and env.spec.kwargs["dtype"] == "float32"
    assert env.single_observation_space.shape == (2 * 79,)
    assert env.single_action_space.shape == (2 * 8,)
    assert env.observation_space.shape == (3, 158) and env.action_space.shape == (3, 16)
    assert env.observation_space.dtype == env.action_space.dtype == np.float32
    env.close()
    assert env.closed


def test_gym_matches_sync_vector_env_in_same_step_mode():
    batched = _gym()
    sync = gymnasium.make_vec(
        ENV_ID,
        num_envs=2,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
        scenario="short",
        max_cycles=3,
    )
    obs, infos = batched.reset(seed=SEED)
    ref, _ = sync.reset(seed=SEED)
    assert obs.dtype == np.float32 and batched.observation_space.contains(obs)
    np.testing.assert_allclose(obs, ref, atol=OBS_ATOL)
    np.testing.assert_array_equal(infos["episode_seed"], [SEED, SEED + 1])
    for t in range(4):
        actions = _actions(2, t, 16)
        obs, rew, term, trunc, infos = batched.step(actions)
        r_obs, r_rew, r_term, r_trunc, r_infos = sync.step(actions)
        assert batched.observation_space.contains(obs)
        assert rew.shape == term.shape == trunc.shape == (2,)
        assert term.dtype == trunc.dtype == bool
        np.testing.assert_allclose(obs, r_obs, atol=OBS_ATOL)
        np.testing.assert_allclose(rew, r_rew, atol=1e-6)
        np.testing.assert_array_equal(term, r_term)
        np.testing.assert_array_equal(trunc, r_trunc)
        ended = t == 2
        assert ("final_obs" in infos) == ("final_obs" in r_infos) == ended
        team = [k for k in r_infos if not k.startswith("_") and k not in ("agents", "final_obs")]
        team = [k for k in team if k != "final_info"]
        assert set(team) | {"constraint_values"} == {
            k for k in infos if not k.startswith("_") and k not in ("final_obs", "final_info")
        }
        for key in team:  # every key of the single view's team info, with its mask
            assert infos[key].dtype == r_infos[key].dtype, key
            np.testing.assert_allclose(infos[key], r_infos[key], atol=1e-6, err_msg=key)
            np.testing.assert_array_equal(infos[f"_{key}"], r_infos[f"_{key}"], err_msg=key)
        if ended:
            np.testing.assert_array_equal(infos["_final_obs"], r_infos["_final_obs"])
            np.testing.assert_array_equal(infos["_final_info"], r_infos["_final_info"])
            for i in range(2):
                assert batched.single_observation_space.contains(infos["final_obs"][i])
                np.testing.assert_allclose(
                    infos["final_obs"][i], r_infos["final_obs"][i], atol=OBS_ATOL
                )
            final, r_final = infos["final_info"], r_infos["final_info"]
            assert final["episode_end"].tolist() == [end_code("max_cycles")] * 2
            for key in (k for k in r_final if not k.startswith("_") and k != "agents"):
                assert final[key].dtype == r_final[key].dtype, key
                np.testing.assert_allclose(
                    final[key], r_final[key], atol=1e-6, err_msg=key, equal_nan=True
                )
    batched.close()
    sync.close()


def test_gym_reset_seeding():
    env = _gym(3)
    first, _ = env.reset(seed=11)
    again, _ = env.reset(seed=[11, 12, 13])
    np.testing.assert_array_equal(first, again)
    other, _ = env.reset(seed=12)
    np.testing.assert_array_equal(other[:2], first[1:])
    assert env.np_random_seed == 12
    env.reset(seed=[None, None, None])  # every env's own sequence
    with pytest.raises(ValueError, match="all ints or all None"):
        env.reset(seed=[1, None, 2])
    with pytest.raises(ValueError, match="2 seeds for 3 environments"):
        env.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(options={"reset_mask": np.ones(3, bool)})
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 8), np.float32))
    env.close()


def test_gym_vector_wrappers_read_the_infos():
    from gymnasium.wrappers.vector import DictInfoToList, RecordEpisodeStatistics

    env = RecordEpisodeStatistics(_gym())
    env.reset(seed=0)
    for t in range(3):
        *_, infos = env.step(_actions(2, t, 16))
    np.testing.assert_array_equal(infos["episode"]["l"], [3, 3])
    assert list(env.length_queue) == [3, 3]
    listed = DictInfoToList(_gym())
    listed.reset(seed=0)
    for t in range(3):
        *_, infos = listed.step(_actions(2, t, 16))
    assert len(infos) == 2 and infos[0]["final_info"]["episode_end"] == end_code("max_cycles")
    assert {"final_obs", "final_info", "success", "cost"} <= set(infos[1])
