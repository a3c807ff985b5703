"""TorchRL users see the benchmark's metrics: TorchRL's own ``PettingZooWrapper`` over
``FlatInfos(parallel_env(...))`` carries every info key, and the batched TorchRL view with
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
from uvms_env.vector import VectorEnv
from uvms_env.vector.torchrl_env import (
    GROUP,
    CoopTransportTorchRLEnv,
    FlatInfos,
    episode_info_keys,
)

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


def test_flat_infos_is_a_pettingzoo_parallel_env():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(FlatInfos(uvms_env.parallel_env("short", max_cycles=20)), num_cycles=30)


def test_the_bare_parallel_env_passes_torchrls_checks_without_infos():
    env = PettingZooWrapper(env=uvms_env.parallel_env("short", max_cycles=CYCLES))
    check_env_specs(env)
    assert "info" not in env.observation_spec[GROUP].keys()


def test_pettingzoo_wrapper_rollout_carries_the_info_keys_and_their_values():
    flat = FlatInfos(uvms_env.parallel_env("short", max_cycles=CYCLES))
    env = PettingZooWrapper(env=flat, return_state=True, seed=3)
    check_env_specs(env)
    keys = set(env.observation_spec[GROUP, "info"].keys())
    assert keys == set(flat.info_keys)
    assert {"cost", "success", "clean_success", "violation_periods", "episode_cost"} <= keys
    assert {"constraint_collision", "reward_progress", "violations_collision"} <= keys

    actions = _actions(CYCLES, 2)
    policy = _replaying(actions)
    env.set_seed(3)
    rollout = env.rollout(CYCLES, policy)
    info = rollout["next", GROUP, "info"]
    assert set(info.keys()) == keys and info["cost"].shape == (CYCLES, 2)

    reference = uvms_env.parallel_env("short", max_cycles=CYCLES)
    reference.reset(seed=3)
    cost = np.zeros(2)
    for t in range(CYCLES):
        *_, infos = reference.step({f"uvms_{i}": actions[t, i] for i in range(2)})
        for i in range(2):
            mine = infos[f"uvms_{i}"]
            cost[i] += mine["cost"]
            assert info["cost"][t, i] == mine["cost"], t
            g = mine["constraint_values"]["collision"]
            assert info["constraint_collision"][t, i] == pytest.approx(g, rel=1e-6)
    metrics = infos["uvms_0"]["metrics"]  # the last step's: the episode's
    assert rollout["next", "done"][-1].all() and not rollout["next", "done"][:-1].any()
    last = {key: info[key][-1] for key in flat.episode_keys}
    assert last["episode_steps"].tolist() == [CYCLES] * 2
    assert last["violation_periods"].tolist() == [metrics["violation_periods"]] * 2
    assert last["success"].tolist() == [float(metrics["success"])] * 2
    assert last["episode_cost"].tolist() == cost.tolist()
    assert not info["episode_steps"][:-1].any()  # zero before the episode's end


def test_batched_view_carries_the_ended_episodes_values():
    k, steps = 3, 2 * CYCLES
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=k, max_cycles=CYCLES), info=True)
    check_env_specs(env)
    assert set(env.observation_spec[GROUP, "info"].keys()) == {"cost", *env.episode_keys}
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
        for e in range(k):
            metrics = infos["metrics"][e]
            if metrics is None:
                assert not info["episode_steps"][e, t].any()
                continue
            for key in ("success", "clean_success", "violation_periods", "episode_steps"):
                assert info[key][e, t].tolist() == [float(metrics[key])] * 2, (key, e, t)
            kinds = metrics["violations"]
            assert info["violations_joint_speed"][e, t, 0] == kinds["joint_speed"]
            assert info["episode_cost"][e, t].tolist() == cost[e].tolist()
            cost[e] = 0
    assert rollout["next", "done"].sum() == 2 * k


def test_episode_keys_follow_the_constraints_and_the_wrench_setting():
    keys = episode_info_keys(("input", "mine"), internal_wrench=False)
    assert keys[-3:] == ("violations_input", "violations_mine", "episode_cost")
    assert episode_info_keys((), internal_wrench=True)[-1] == "internal_wrench_rms"


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
