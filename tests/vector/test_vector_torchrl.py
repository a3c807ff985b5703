"""The TorchRL view of ``VectorEnv``: TorchRL's own spec check, the multi-agent group layout,
and episodes equal to the VectorEnv's, ends and resets included; over the CUDA backend
(its kernels compiled for the host, ``device="cpu"``) the same rollout in tensors that
never leave the env's device."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torchrl")

import torch
from torchrl.envs.utils import check_env_specs, step_mdp

from uvms_env.vector import VectorEnv
from uvms_env.vector.torchrl_env import GROUP, CoopTransportTorchRLEnv

EMULATED_CUDA = {"backend": "cuda", "device": "cpu"}


def test_specs_pass_torchrl_checks_and_use_one_agent_group():
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=3, max_cycles=4))
    check_env_specs(env)
    td = env.reset()
    assert td[GROUP, "observation"].shape == (3, 2, 79)
    assert env.action_spec[GROUP, "action"].shape == (3, 2, 8)
    assert env.group_map == {GROUP: ["uvms_0", "uvms_1"]}


def test_rollout_equals_the_vector_env_through_ends_and_resets():
    k, steps = 3, 10
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=k, max_cycles=4))
    env.set_seed(5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, k, 2, 8)).astype(np.float32)
    step = [0]

    def policy(td):
        td[GROUP, "action"] = torch.as_tensor(actions[step[0]])
        step[0] += 1
        return td

    rollout = env.rollout(steps, policy, break_when_any_done=False)
    reference = VectorEnv("short", num_envs=k, max_cycles=4)
    obs, _ = reference.reset(seed=5)
    for t in range(steps):
        assert np.array_equal(rollout[GROUP, "observation"][:, t].numpy(), obs), t
        obs, reward, terminated, truncated, infos = reference.step(actions[t])
        ended = terminated | truncated
        last = np.where(ended[:, None, None], infos["final_observation"], obs)
        assert np.array_equal(rollout["next", GROUP, "observation"][:, t].numpy(), last), t
        assert np.allclose(rollout["next", GROUP, "reward"][:, t, :, 0].numpy(), reward[:, None])
        assert np.array_equal(rollout["next", "done"][:, t, 0].numpy(), ended)
        assert np.array_equal(rollout["next", "truncated"][:, t, 0].numpy(), truncated)
    assert rollout["next", "done"].sum() == 2 * k  # two ends each: the resets were exercised


@pytest.mark.parametrize(
    ("backend", "emulated_xp"),
    [({}, "numpy"), (EMULATED_CUDA, "numpy"), (EMULATED_CUDA, "strict")],
    ids=["cpu", "emulated-cuda", "emulated-cuda-strict"],
    indirect=["emulated_xp"],
)
def test_partial_reset_restarts_only_the_masked_environments(backend, emulated_xp):
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=2, **backend))
    td = env.reset()
    start = td[GROUP, "observation"].clone()
    td[GROUP, "action"] = torch.full((2, 2, 8), 0.5)
    carried = step_mdp(env.step(td))  # what a collector resets from
    moved = carried[GROUP, "observation"].clone()
    carried["_reset"] = torch.tensor([[True], [False]])
    out = env.reset(carried)
    assert torch.equal(out[GROUP, "observation"][1], moved[1])  # env 1 goes on
    # env 0 starts its next episode: same geometry, at rest, as the first one began
    assert torch.equal(out[GROUP, "observation"][0], start[0])
    assert not torch.equal(moved[0], start[0])


def _fixed_rollout(env: CoopTransportTorchRLEnv, actions: torch.Tensor):
    step = [0]

    def policy(td):
        td[GROUP, "action"] = actions[step[0]].to(env.device)
        step[0] += 1
        return td

    env.set_seed(3)
    return env.rollout(len(actions), policy, break_when_any_done=False)


def test_cuda_backend_gives_the_cpu_backends_rollout_in_tensors_on_its_device(emulated_xp):
    """float64, fixed actions, max_cycles 3 over 7 steps: two automatic resets each."""
    k, steps = 3, 7
    actions = torch.as_tensor(
        np.random.default_rng(1).uniform(-1, 1, (steps, k, 2, 8)), dtype=torch.float32
    )
    cpu = _fixed_rollout(CoopTransportTorchRLEnv(VectorEnv("short", k, max_cycles=3)), actions)
    venv = VectorEnv("short", k, max_cycles=3, **EMULATED_CUDA)
    env = CoopTransportTorchRLEnv(venv)
    assert env.device == torch.device("cpu")
    check_env_specs(env)
    cuda = _fixed_rollout(env, actions)
    assert cuda["next", "done"].sum() == 2 * k  # the automatic resets were exercised
    assert set(cuda.keys(True, True)) == set(cpu.keys(True, True))
    for key in cpu.keys(True, True):
        a, b = cpu[key], cuda[key]
        assert b.device == env.device and b.dtype == a.dtype and b.shape == a.shape, key
        if a.dtype == torch.bool:
            assert torch.equal(a, b), key
        else:
            assert torch.allclose(a.double(), b.double(), rtol=0.0, atol=1e-9), key
