"""TorchRL's PPO over the TorchRL view of ``VectorEnv`` (``--library torchrl``): a couple of
iterations write the run folder and the saved actor acts through the evaluator; over the
CUDA backend (its kernels compiled for the host, ``device="cpu"``) the rollout stays in
tensors on the env's device; on a GPU, where there is one, the whole loop does."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

# 0.14: the Collector class (BenchMARL's venv holds 0.11, where the env tests still run)
pytest.importorskip("torchrl", minversion="0.14")

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

import uvms_env
from baselines.evaluation.runner import evaluate
from baselines.loaders.sources import PolicySource
from baselines.rl import torchrl_ppo
from baselines.runs import RunSettings
from baselines.train import main, train
from uvms_env.policy import AgentSpec
from uvms_env.vector.torchrl_env import GROUP

# 4 copies x 8 steps x 2 robots = 64 robot-steps an iteration: 100 take two
TINY = ["--hp", "rollout_steps=8", "--hp", "minibatches=2", "--hp", "epochs=2"]
TINY_HP = {"rollout_steps": 8, "minibatches": 2, "epochs": 2}


def _rows(path) -> list[dict[str, str]]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_two_iterations_write_the_run_folder_and_the_actor_acts(tmp_path):
    out = tmp_path / "run"
    main(
        [
            *("--library", "torchrl", "--algo", "ppo", "--scenario", "short", "--num-envs", "4"),
            *("--robot-steps", "100", "--seed", "3", "--out", str(out), "--no-progress", *TINY),
            *("--env-option", "max_cycles=6"),  # episodes end inside the rollouts
        ]
    )
    config = json.loads((out / "config.json").read_text())
    assert config["command"].startswith("python -m baselines.train --library torchrl --algo ppo")
    own = config["library_settings"]
    assert config["robot_steps"] == 128 and own["robot_steps_per_iteration"] == 64
    assert config["seed"] == 3 and own["backend"] == "cpu" and own["device"] == "cpu"
    assert config["robot_steps_per_s"] > 0 and config["wall_time_s"] > 0
    assert config["hardware"]["cores"] >= 1 and config["overrides"] == {"max_cycles": 6}
    rows = _rows(out / "progress.csv")
    assert [int(r["robot_steps"]) for r in rows] == [64, 128]
    # 8 steps of 6-step episodes per copy and iteration: 4 copies end one in each
    assert [int(r["episodes"]) for r in rows] == [4, 4]
    assert all(float(r["episode_len_mean"]) == 6.0 for r in rows)
    assert len(config["eval"]["episodes"]) == 2  # the recorded evaluation of the final actor

    # the saved actor through the evaluator's policy source, on a single environment
    env = uvms_env.parallel_env(scenario="short")
    obs, _ = env.reset(seed=0)
    policy = PolicySource.parse(f"torchrl:{out}").factory(0)(
        AgentSpec.from_scenario(env.scenario, 0)
    )
    policy.reset()
    action = policy.act(obs["uvms_0"])
    assert action.shape == (8,) and action.dtype == np.float32
    assert np.all(np.abs(action) <= 1.0) and np.any(action != 0.0)

    rows = evaluate([f"torchrl:{out}"], ["short"], 1, 0, 1, max_cycles=5, progress=False)
    assert rows[0]["error"] in ("", None) and rows[0]["episode_steps"] == 5


def test_the_loader_acts_as_the_actors_deterministic_sample():
    env = torchrl_ppo.make_env("short", 2, "cpu", "cpu", "float64", None, 1, {})
    actor, _, actor_net, _ = torchrl_ppo.build_modules(env, torchrl_ppo.HYPERPARAMETERS)
    with torch.no_grad():
        actor_net.body[-1].bias.uniform_(-1.0, 1.0)  # away from zero, as a trained actor
        actor_net.norm.update(torch.randn(64, actor_net.norm.mean.shape[0]))
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        expected = actor(td)[GROUP, "action"]
    with torch.no_grad():
        loc, _ = actor_net(td[GROUP, "observation"])
    assert torch.allclose(torch.tanh(loc), expected, atol=1e-6)


def _collect_on(backend: str, device: str | int) -> None:
    """One PPO iteration's rollout and update on ``backend``: every tensor of the batch on
    the env's device, and actions handed to the VectorEnv as tensors (no numpy)."""
    env = torchrl_ppo.make_env("short", 3, backend, device, "float32", 1024, 1, {"max_cycles": 4})
    assert env.vector_env.backend == backend and env.device == torchrl_ppo.torch_device(device)
    handed: list[type] = []
    step = env.vector_env.step

    def spy(actions):
        handed.append(type(actions))
        return step(actions)

    env.vector_env.step = spy
    actor, critic, _, _ = torchrl_ppo.build_modules(env, torchrl_ppo.HYPERPARAMETERS)
    env.set_seed(0)
    with torch.no_grad():
        batch = env.rollout(6, actor, break_when_any_done=False)
        critic(batch)
    assert batch["next", "done"].sum() == 3  # each copy ended (max_cycles) and went on
    leaves = batch.values(include_nested=True, leaves_only=True)
    assert all(x.device == env.device for x in leaves)
    assert handed == [torch.Tensor] * 6


def test_the_cuda_backend_keeps_the_rollout_in_tensors_on_the_env_device(tmp_path, emulated_xp):
    _collect_on("cuda", "cpu")
    settings = RunSettings(
        "short",
        {"max_cycles": 6},
        100,
        4,
        0,
        tmp_path / "cuda",
        record_eval=False,
        hyperparameters=TINY_HP,
        progress=False,
    )
    out = train("torchrl", "ppo", settings, backend="cuda", device="cpu")
    config = json.loads((out / "config.json").read_text())
    own = config["library_settings"]
    assert own["backend"] == "cuda" and own["device"] == "cpu"
    assert config["robot_steps"] == 128 and (out / torchrl_ppo.ACTOR_FILE).exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_on_a_gpu_everything_stays_there(tmp_path):
    pytest.importorskip("cupy")
    _collect_on("cuda", 0)
    settings = RunSettings("short", {}, 10_000, 64, 0, tmp_path / "gpu", progress=False)
    out = train("torchrl", "ppo", settings, backend="cuda", device=0)
    config = json.loads((out / "config.json").read_text())
    assert config["library_settings"]["device"] == "cuda:0" and "gpu" in config["hardware"]
