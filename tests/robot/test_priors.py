"""The action and observation options (``uvms_env.robot.priors``): their meaning in the
single and the batched environment, and the policies trained with them."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from features_reference import featurize_reference

import uvms_env
from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.local_model import ModelParams, build_local_model, build_steady_input
from uvms_env.dynamics.uvms import default_model
from uvms_env.policy import AgentSpec
from uvms_env.robot.priors import FEATURES_SIZE, Priors, steady_inputs

MODES = {"action_mode": "residual", "observation_mode": "features"}


def _stack(obs: dict[str, np.ndarray], env) -> np.ndarray:
    return np.stack([obs[a] for a in env.possible_agents])


@functools.cache
def _steady_function(shape: str, object_size: float):
    obj = ObjectModel(shape, object_size)
    return build_steady_input(default_model(), obj, build_local_model(default_model(), obj))


def _experts_steady(env, raw: np.ndarray) -> np.ndarray:
    """a_ss through the expert's path: grasp, share and object from each robot's spec."""
    out = []
    for i in range(env.n):
        spec = AgentSpec.from_scenario(env.scenario, i)
        obj = ObjectModel(spec.object_shape, spec.object_size)
        fn = _steady_function(spec.object_shape, spec.object_size)
        theta = ModelParams(
            spec.grasp_offset, spec.grasp_rotation, spec.load_share, obj.nominal_parameters()
        ).pack()
        o = raw[i].astype(float)
        out.append(np.asarray(fn(o[:20], theta, o[44:50])).ravel())
    return np.array(out)


def test_residual_and_features_are_the_plain_env_driven_through_a_ss():
    """The options change what the policy sees and how its action becomes the input,
    nothing else: a residual env and a plain env fed clip(a_ss + 0.3 clip(r)) stay in the
    same state, and the features are the plain observation's (the numpy reference) and
    its a_ss."""
    with_priors = uvms_env.parallel_env("short", internal_wrench_every=0, **MODES)
    plain = uvms_env.parallel_env("short", internal_wrench_every=0)
    obs_p, _ = with_priors.reset(seed=3)
    obs_0, _ = plain.reset(seed=3)
    assert with_priors.observation_space("uvms_0").shape == (FEATURES_SIZE,)
    rng = np.random.default_rng(0)
    for _ in range(12):
        raw, seen = _stack(obs_0, plain), _stack(obs_p, with_priors)
        steady = _experts_steady(plain, raw)
        assert np.allclose(seen[:, :76], featurize_reference(raw), atol=1e-6)
        assert np.allclose(seen[:, 76:], steady, atol=1e-6)
        assert all(with_priors.observation_space(a).contains(obs_p[a]) for a in obs_p)
        r = rng.uniform(-1.3, 1.3, (2, 8))
        command = np.clip(steady + 0.3 * np.clip(r, -1, 1), -1, 1)
        obs_p, _, _, _, info_p = with_priors.step(
            dict(zip(with_priors.possible_agents, r, strict=True))
        )
        obs_0, _, _, _, info_0 = plain.step(dict(zip(plain.possible_agents, command, strict=True)))
        # the expert's a_ss here runs in CasADi's VM, the env's in generated C: 1e-12 apart
        np.testing.assert_allclose(with_priors.sim.flat_state, plain.sim.flat_state, atol=1e-7)
        # what is measured is the applied input, as in the plain env fed it: the input
        # constraint and the effort term see the command, not the residual
        for agent in plain.possible_agents:
            assert info_p[agent] == pytest.approx(info_0[agent], abs=1e-6), agent
        g_input = info_p["uvms_0"]["constraint_input"]
        assert g_input == pytest.approx(np.abs(command[0]).max() - 1.0, abs=1e-6)


def test_vector_env_applies_the_same_priors_as_single_envs():
    from uvms_env.vector import VectorEnv

    k = 2
    venv = VectorEnv("short", num_envs=k, dtype="float64", max_cycles=6, **MODES)
    singles = [uvms_env.parallel_env("short", max_cycles=6, **MODES) for _ in range(k)]
    obs_v, _ = venv.reset(seed=5)
    obs_s = [_stack(e.reset(seed=5 + i)[0], e) for i, e in enumerate(singles)]
    assert venv.observation_space.shape == (k, 2, FEATURES_SIZE)
    rng = np.random.default_rng(1)
    for step in range(8):  # through an automatic reset at step 6
        for i in range(k):
            np.testing.assert_allclose(obs_v[i], obs_s[i], atol=1e-6, err_msg=f"step {step}")
        r = rng.uniform(-1, 1, (k, 2, 8))
        obs_v, reward, _, truncated, infos = venv.step(r)
        for i, env in enumerate(singles):
            o, rew, _, trunc, _ = env.step(dict(zip(env.possible_agents, r[i], strict=True)))
            assert reward[i] == pytest.approx(rew["uvms_0"], abs=1e-9)
            if trunc["uvms_0"]:
                np.testing.assert_allclose(infos["final_observation"][i], _stack(o, env), atol=1e-6)
                o, _ = env.reset()
            obs_s[i] = _stack(o, env)
        assert truncated.all() == (step == 5)


def test_joint_hold_is_the_plain_env_driven_through_a_ss_and_the_hold():
    """With hold gains, the residual env is the plain env driven by clip(a_ss + h + 0.3 r),
    h = -kp (q - q_nom) - kd qdot on the four arm inputs only (q_nom the nominal arm
    pose), from the robot's own measured joints; the vector env applies the same."""
    from uvms_env.scenarios.geometry import NOMINAL_ARM
    from uvms_env.vector import VectorEnv

    kp, kd = 0.5, 1.0
    hold = {"action_mode": "residual", "hold_stiffness": kp, "hold_damping": kd}
    with_hold = uvms_env.parallel_env("short", internal_wrench_every=0, **hold)
    plain = uvms_env.parallel_env("short", internal_wrench_every=0)
    venv = VectorEnv("short", num_envs=1, dtype="float64", internal_wrench_every=0, **hold)
    obs_h, _ = with_hold.reset(seed=4)
    obs_0, _ = plain.reset(seed=4)
    obs_v, _ = venv.reset(seed=4)
    rng = np.random.default_rng(2)
    for _ in range(10):
        raw = _stack(obs_0, plain).astype(float)
        h = np.zeros((2, 8))
        h[:, 4:] = -kp * (raw[:, 6:10] - NOMINAL_ARM) - kd * raw[:, 16:20]
        r = rng.uniform(-1, 1, (2, 8))
        command = np.clip(_experts_steady(plain, raw) + h + 0.3 * r, -1, 1)
        obs_h, *_ = with_hold.step(dict(zip(with_hold.possible_agents, r, strict=True)))
        obs_0, *_ = plain.step(dict(zip(plain.possible_agents, command, strict=True)))
        obs_v, *_ = venv.step(r[None])
        np.testing.assert_allclose(with_hold.sim.flat_state, plain.sim.flat_state, atol=1e-7)
        np.testing.assert_allclose(obs_v[0], _stack(obs_h, with_hold), atol=1e-6)
    assert np.abs(h[:, 4:]).max() > 1e-3  # the hold acted


def test_setpoint_mode_is_the_plain_env_driven_by_the_loop_around_the_holding_a_ss():
    """action_mode="setpoint": the plain env driven by clip(a_ss0 + K (clip(a) - zeta_a /
    limit), -1, 1): a_ss0 the expert's steady input at a zero navigation twist (what holds
    the robot still with its load), zeta_a the robot's measured surge, sway, heave, yaw
    rate and joint rates, the limits the model's, K the robot's own inertia on each vehicle
    velocity over setpoint_time (per saturation) and setpoint_joint_gain on the joints; the
    vector env applies the same, and the input constraint sees the command."""
    from uvms_env.dynamics.uvms import default_model
    from uvms_env.robot.observation import OBSERVATION_STRUCTURE
    from uvms_env.scenarios.geometry import NOMINAL_ARM
    from uvms_env.vector import VectorEnv

    mode = {"action_mode": "setpoint", "setpoint_time": 0.4, "setpoint_joint_gain": 0.08}
    with_loop = uvms_env.parallel_env("short", internal_wrench_every=0, **mode)
    plain = uvms_env.parallel_env("short", internal_wrench_every=0)
    venv = VectorEnv("short", num_envs=1, dtype="float64", internal_wrench_every=0, **mode)
    obs_l, _ = with_loop.reset(seed=6)
    obs_0, _ = plain.reset(seed=6)
    venv.reset(seed=6)
    uvms = default_model()
    lim = uvms.params.limits
    scale = np.array([lim.vehicle_linear_speed] * 3 + [lim.vehicle_angular_speed])
    scale = np.r_[scale, [lim.joint_speed] * 4]
    mass = np.diag(
        np.array(uvms.mass_matrix(np.r_[np.zeros(6), NOMINAL_ARM], uvms.nominal_parameters()))
    )
    actuated = [0, 1, 2, 5, 6, 7, 8, 9]
    gain = mass[actuated] * scale / (0.4 * np.asarray(lim.tau_max, float))
    gain[4:] = 0.08
    nav, zeta = OBSERVATION_STRUCTURE["nav_velocity"], OBSERVATION_STRUCTURE["zeta"]
    rng = np.random.default_rng(3)
    for _ in range(8):
        raw = _stack(obs_0, plain).astype(float)
        held = raw.copy()
        held[:, nav] = 0.0
        a = rng.uniform(-1.4, 1.4, (2, 8))
        speed = raw[:, zeta][:, actuated] / scale
        command = np.clip(_experts_steady(plain, held) + gain * (np.clip(a, -1, 1) - speed), -1, 1)
        obs_l, _, _, _, info_l = with_loop.step(
            dict(zip(with_loop.possible_agents, a, strict=True))
        )
        obs_0, _, _, _, info_0 = plain.step(dict(zip(plain.possible_agents, command, strict=True)))
        obs_v, *_ = venv.step(a[None])
        np.testing.assert_allclose(with_loop.sim.flat_state, plain.sim.flat_state, atol=1e-7)
        np.testing.assert_allclose(obs_v[0], _stack(obs_l, with_loop), atol=1e-6)
        for agent in plain.possible_agents:
            assert info_l[agent]["constraint_input"] == pytest.approx(
                info_0[agent]["constraint_input"], abs=1e-9
            )
    assert np.abs(gain * speed).max() > 1e-3  # the loop acted


def test_setpoint_loop_holds_a_constant_set_point_within_the_limits():
    """A zero set-point holds the team still after the start's transient (no speed limit
    broken in the last 60 periods); a surge set-point of 0.2 of the limit moves every
    vehicle forward at a steady speed below it, nothing else past its limit."""
    from uvms_env.robot.priors import SETPOINT_ZETA, setpoint_limits

    def run(target: np.ndarray) -> tuple[np.ndarray, list]:
        env = uvms_env.parallel_env("short", max_cycles=120, action_mode="setpoint")
        env.reset(seed=1)
        speeds, late = [], []
        while env.agents:
            *_, infos = env.step({a: target for a in env.agents})
            speeds.append(env.sim.state.zeta[:, list(SETPOINT_ZETA)] / setpoint_limits())
            late.append(max(infos[a]["cost"] for a in env.possible_agents))
        return np.array(speeds), late

    still, late = run(np.zeros(8))
    assert np.abs(still[-60:]).max() < 0.2 and max(late[-60:]) == 0
    surge = np.zeros(8)
    surge[0] = 0.2
    moving, late = run(surge)
    forward = moving[-30:, :, 0]
    assert 0.05 < forward.mean() < 0.2 and forward.std() < 0.02  # steady, below its set-point
    assert np.abs(moving[-60:]).max() <= 1.0 and max(late[-60:]) == 0


def test_bad_modes_name_the_option():
    with pytest.raises(ValueError, match="action_mode"):
        uvms_env.parallel_env("short", action_mode="force")
    with pytest.raises(ValueError, match="observation_mode"):
        uvms_env.parallel_env("short", observation_mode="pixels")
    with pytest.raises(ValueError, match="residual_scale"):
        uvms_env.parallel_env("short", residual_scale=0.0)
    with pytest.raises(ValueError, match="observations"):
        steady_inputs(np.zeros((3, 78)), 0.0)
    with pytest.raises(ValueError, match="residual"):
        uvms_env.parallel_env("short", hold_stiffness=0.5)  # torque mode has no base input
    with pytest.raises(ValueError, match="hold_damping"):
        uvms_env.parallel_env("short", action_mode="residual", hold_damping=-1.0)
    with pytest.raises(ValueError, match="setpoint_time"):
        uvms_env.parallel_env("short", action_mode="setpoint", setpoint_time=0.0)
    with pytest.raises(ValueError, match="setpoint_joint_gain"):
        uvms_env.parallel_env("short", action_mode="setpoint", setpoint_joint_gain=2.0)


def test_sb3_policy_rebuilds_the_runs_priors(tmp_path):
    """A model trained with the options acts through the plain interface: it featurizes
    the raw observation itself and returns clip(a_ss + s r)."""
    from stable_baselines3 import PPO

    from baselines.loaders.sb3_policy import SB3Policy
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv

    modes = {**MODES, "residual_scale": 0.5}
    venv = VectorVecEnv(VectorEnv("short", 1, **modes))
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, seed=0)
    model.save(tmp_path / "model.zip")
    (tmp_path / "config.json").write_text(json.dumps({"overrides": modes}))
    env = uvms_env.parallel_env("short")
    obs, _ = env.reset(seed=2)
    raw = _stack(obs, env)
    for i, agent in enumerate(env.possible_agents):
        policy = SB3Policy(AgentSpec.from_scenario(env.scenario, i), "ppo", tmp_path)
        seen = Priors(observation_mode="features").observe(raw[i], 0.0)
        r, _ = model.predict(seen, deterministic=True)
        steady = _experts_steady(env, raw)[i]
        want = np.clip(steady + 0.5 * np.clip(r, -1, 1), -1, 1)
        np.testing.assert_allclose(policy.act(obs[agent]), want, atol=1e-6)
