"""TorchRL users see the benchmark's metrics: TorchRL's own ``PettingZooWrapper`` over the
plain ``parallel_env(...)`` carries every info key, and the batched TorchRL view with
``info=True`` the same episode values, equal to the environments' own; its ``fixed_seed``
replays the episodes of every fresh reset, and it renders a copy as the parallel env does,
without the step ever importing what draws. Skipped without TorchRL."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("torchrl")

import torch
from torchrl.envs import PettingZooWrapper
from torchrl.envs.utils import check_env_specs

import uvms_env
from uvms_env.env.infos import EPISODE_END_NAMES, end_code, episode_metrics
from uvms_env.vector import VectorEnv
from uvms_env.vector.torchrl_env import GROUP, CoopTransportTorchRLEnv, episode_info_keys

CYCLES = 4


def _replaying(actions: np.ndarray):
    """A TorchRL policy that writes ``actions[t]`` at its t-th call."""
    step = [0]

    def policy(td):
        td[GROUP, "action"] = torch.as_tensor(actions[step[0]])
        step[0] += 1
        return td

    return policy


def _actions(steps: int, n: int, k: int | None = None) -> np.ndarray:
    shape = (steps, n, 8) if k is None else (steps, k, n, 8)
    return np.random.default_rng(0).uniform(-1, 1, shape).astype(np.float32)


def test_the_plain_env_infos_are_numbers_with_the_same_keys_at_reset_and_every_step():
    env = uvms_env.parallel_env("short", max_cycles=CYCLES)
    _, infos = env.reset(seed=1)
    keys = list(env.info_keys)
    assert all(list(i) == keys for i in infos.values())
    actions = _actions(CYCLES, 2)
    for t in range(CYCLES):
        *_, infos = env.step({f"uvms_{i}": actions[t, i] for i in range(2)})
        for info in infos.values():
            assert list(info) == keys
            assert all(isinstance(v, int | float) for v in info.values()), info
    assert infos["uvms_0"]["episode_end"] == EPISODE_END_NAMES.index("max_cycles")


def test_pettingzoo_wrapper_rollout_of_the_plain_env_carries_the_infos_and_their_values():
    plain = uvms_env.parallel_env("short", max_cycles=CYCLES)
    env = PettingZooWrapper(env=plain, return_state=True, seed=3)
    check_env_specs(env)
    keys = set(env.observation_spec[GROUP, "info"].keys())
    assert keys == set(plain.info_keys)
    assert {"cost", "success", "clean_success", "clean_success_tol", "return"} <= keys
    assert {"constraint_collision", "reward_progress", "excess_joint_speed"} <= keys

    actions = _actions(CYCLES, 2)
    policy = _replaying(actions)
    env.set_seed(3)
    rollout = env.rollout(CYCLES, policy)
    info = rollout["next", GROUP, "info"]
    assert set(info.keys()) == keys and info["cost"].shape == (CYCLES, 2)

    reference = uvms_env.parallel_env("short", max_cycles=CYCLES)
    reference.reset(seed=3)
    for t in range(CYCLES):
        *_, infos = reference.step({f"uvms_{i}": actions[t, i] for i in range(2)})
        for i in range(2):
            mine = infos[f"uvms_{i}"]
            assert info["cost"][t, i] == mine["cost"], t
            g = mine["constraint_collision"]
            assert info["constraint_collision"][t, i] == pytest.approx(g, rel=1e-6)
    metrics = episode_metrics(infos["uvms_0"])  # the last step's: the episode's
    assert rollout["next", "done"][-1].all() and not rollout["next", "done"][:-1].any()
    for key in ("episode_steps", "violation_periods", "success", "excess", "return"):
        assert info[key][-1].tolist() == pytest.approx([float(metrics[key])] * 2, rel=1e-6)
    assert info["episode_steps"][-1].tolist() == [CYCLES] * 2
    assert not info["episode_steps"][:-1].any()  # zero before the episode's end


def test_batched_view_carries_the_ended_episodes_values():
    k, steps = 3, 2 * CYCLES
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=k, max_cycles=CYCLES), info=True)
    check_env_specs(env)
    assert set(env.observation_spec[GROUP, "info"].keys()) == {*env.step_keys, *env.episode_keys}
    # the plain env's names for the values they share (PettingZooWrapper's infos above)
    plain_keys = set(uvms_env.parallel_env("short").info_keys)
    assert {*env.step_keys, *env.episode_keys} - plain_keys == {"episode_cost"}
    actions = _actions(steps, 2, k)
    policy = _replaying(actions)
    env.set_seed(5)
    rollout = env.rollout(steps, policy, break_when_any_done=False)
    info = rollout["next", GROUP, "info"]
    reference = VectorEnv("short", num_envs=k, max_cycles=CYCLES)
    reference.reset(seed=5)
    cost = np.zeros((k, 2))
    for t in range(steps):
        *_, infos = reference.step(actions[t])
        cost += infos["cost"]
        assert np.array_equal(info["cost"][:, t].numpy(), infos["cost"]), t
        g = infos["constraint_values"].astype(np.float32)  # (K, N, kinds)
        assert np.array_equal(info["constraint_joint_speed"][:, t].numpy(), g[..., 2]), t
        for e in range(k):
            metrics = infos["metrics"][e]
            if metrics is None:
                assert not info["episode_steps"][e, t].any()
                continue
            for key in ("success", "clean_success", "violation_periods", "episode_steps"):
                assert info[key][e, t].tolist() == [float(metrics[key])] * 2, (key, e, t)
            code = end_code(infos["episode_end"][e])
            assert info["episode_end"][e, t].tolist() == [float(code)] * 2
            assert info["violations_joint_speed"][e, t, 0] == metrics["violations_joint_speed"]
            assert info["episode_cost"][e, t].tolist() == cost[e].tolist()
            cost[e] = 0
    assert rollout["next", "done"].sum() == 2 * k


def test_episode_keys_follow_the_constraints_and_the_wrench_setting():
    keys = episode_info_keys(("input", "mine"), internal_wrench=False)
    assert {"violations_mine", "excess_mine", "max_excess_mine"} <= set(keys)
    assert keys[-1] == "episode_cost" and "internal_wrench_rms" not in keys
    assert "internal_wrench_rms" in episode_info_keys((), internal_wrench=True)


def test_fixed_seed_replays_the_episodes_of_every_fresh_reset():
    def make(fixed: bool) -> CoopTransportTorchRLEnv:
        venv = VectorEnv("short", num_envs=2, max_cycles=CYCLES, geometry_pool=64)
        env = CoopTransportTorchRLEnv(venv, fixed_seed=fixed)
        env.set_seed(9)
        return env

    fixed, moving = make(True), make(False)
    starts = [fixed.rollout(2)[GROUP, "observation"][:, 0] for _ in range(2)]
    assert torch.equal(starts[0], starts[1])  # the same geometries and starts
    first, second = (moving.rollout(2)[GROUP, "observation"][:, 0] for _ in range(2))
    assert torch.equal(first, starts[0]) and not torch.equal(first, second)


def test_render_draws_a_copy_as_the_parallel_env_does():
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=2, max_cycles=CYCLES))
    env.set_seed(4)
    env.reset()
    single = uvms_env.parallel_env("short", render_mode="rgb_array", max_cycles=CYCLES)
    single.reset(seed=5)  # copy 1 of the vector env reset with seed 4
    frame = env.render(1)
    assert frame.shape == (360, 720, 3) and frame.dtype == np.uint8
    assert np.array_equal(frame, single.render())
    # every second call of the episode draws; in between the last picture comes back
    env.rand_step()
    assert env.render(1, every=2) is frame
    env.rand_step()
    assert env.render(1, every=2) is not frame


def test_the_step_never_draws():
    """The renderer's module is part of the package; what draws (matplotlib) is imported by
    the first ``render`` only."""
    code = (
        "import sys\n"
        "from uvms_env.vector import VectorEnv\n"
        "from uvms_env.vector.torchrl_env import CoopTransportTorchRLEnv\n"
        "env = CoopTransportTorchRLEnv(VectorEnv('short', num_envs=2, max_cycles=3), info=True)\n"
        "env.rollout(4, break_when_any_done=False)\n"
        "assert not any(m.startswith('matplotlib') for m in sys.modules)\n"
        "env.render(0)\n"
        "assert 'matplotlib' in sys.modules\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
