"""BenchMARL as ``baselines.train``'s TorchRL trainer (``--library benchmarl``): the shared
options become BenchMARL's configs (the task of the scenario, the budget in whole
iterations), MASAC trains off-policy under the same run folder, the cost penalty is each
robot's priced cost at its step, and over the CUDA backend (its kernels compiled for the
host, ``device="cpu"``; on a GPU where there is one) the copies step there and the saved
checkpoint plays on the host. Tiny budgets: these check the paths, not the learning."""

from __future__ import annotations

import csv
import json
from argparse import Namespace

import numpy as np
import pytest

pytest.importorskip("benchmarl", reason="the learn extra installs BenchMARL")

import torch

from baselines.lagrangian import CONSTRAINTS, CostSettings, Lagrangian, magnitude_cost
from baselines.rl import benchmarl_trainer
from baselines.runs import RunSettings
from baselines.train import main, train

# 2 copies x 16 steps x 2 robots: 64 robot-steps an iteration, 6-step episodes
TINY_HP = {
    "experiment.on_policy_collected_frames_per_batch": 32,
    "experiment.on_policy_minibatch_size": 16,
    "experiment.on_policy_n_minibatch_iters": 1,
    "model.num_cells": [8],
    "critic_model.num_cells": [8],
}


def _rows(path) -> list[dict[str, str]]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_the_scenario_names_the_task_and_the_budget_rounds_up_to_whole_iterations(tmp_path):
    assert benchmarl_trainer.task_name("random", {"n_agents": 5}) == "random_n5"
    assert benchmarl_trainer.task_name("random", {}) == "random_n2"
    assert benchmarl_trainer.task_name("paper", {}) == "paper"
    with pytest.raises(ValueError, match="2 to 6"):
        benchmarl_trainer.task_name("random", {"n_agents": 7})
    assert benchmarl_trainer.parse_device(None, "cuda") == "cuda:0"
    assert benchmarl_trainer.parse_device("1", "cpu") == "cuda:1"
    out = tmp_path / "mappo"
    main(
        [
            *("--library", "benchmarl", "--scenario", "short", "--num-envs", "2"),
            *("--robot-steps", "100", "--out", str(out), "--no-progress", "--geometry-pool", "0"),
            *("--env-option", "max_cycles=6", "--checkpoint-every", "64"),
            *(arg for key, value in TINY_HP.items() for arg in ("--hp", f"{key}={value}")),
        ]
    )
    config = json.loads((out / "config.json").read_text())
    own = config["library_settings"]
    assert own["task"] == "uvms/short" and own["task_config"]["max_cycles"] == 6
    assert own["robot_steps_per_iteration"] == 64 and config["robot_steps"] == 128
    assert (own["frames"], own["iterations"]) == (64, 2)
    experiment = out / own["experiment_folder"]
    # BenchMARL's checkpoints every iteration (--checkpoint-every 64), the run's own copy
    assert sorted(p.name for p in (experiment / "checkpoints").iterdir()) == [
        "checkpoint_32.pt",
        "checkpoint_64.pt",
    ]
    assert [p.name for p in (out / "checkpoints").iterdir()] == ["checkpoint_64.pt"]
    # the run's copy is BenchMARL's file (a hard link): an off-policy one is gigabytes
    last = experiment / "checkpoints" / "checkpoint_64.pt"
    assert (out / "checkpoints" / "checkpoint_64.pt").samefile(last)
    assert (experiment / experiment.name / "scalars").is_dir()  # BenchMARL's own logs
    assert len(config["eval"]["episodes"]) == 2  # the saved policy played by the evaluator


def test_masac_trains_off_policy_under_the_same_run_folder(tmp_path):
    settings = RunSettings(
        "short",
        {"max_cycles": 6},
        64,
        2,
        0,
        tmp_path / "masac",
        checkpoint_every=0,
        geometry_pool=0,
        hyperparameters={
            "experiment.off_policy_collected_frames_per_batch": 32,
            "experiment.off_policy_n_optimizer_steps": 2,
            "experiment.off_policy_train_batch_size": 16,
            "experiment.off_policy_memory_size": 1000,
            "model.num_cells": [8],
            "critic_model.num_cells": [8],
        },
        progress=False,
    )
    out = train("benchmarl", "masac", settings)
    config = json.loads((out / "config.json").read_text())
    assert config["algo"] == "masac" and config["robot_steps"] == 64
    (row,) = _rows(out / "progress.csv")
    assert int(row["episodes"]) == 4 and float(row["episode_len_mean"]) == 6.0
    assert int(row["ends_max_cycles"]) == 4
    assert config["eval"]["episodes"][0]["episode_steps"] > 0


def test_the_penalty_is_each_robots_priced_cost_at_its_step():
    """``Trainer.collected`` on a batch of the task's env: the reward BenchMARL learns from is
    the env's less the multiplier times the robot's magnitude cost of that step."""
    from torchrl.envs import RewardSum, TransformedEnv

    from baselines.benchmarl_tasks import UVMSTask
    from uvms_env.vector.torchrl_env import GROUP

    task = UVMSTask.SHORT.get_from_yaml()
    task.config.update(max_cycles=4, geometry_pool=None)
    env = task.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    env = TransformedEnv(env, RewardSum(in_keys=[(GROUP, "reward")]))
    batch = env.rollout(6, break_when_any_done=False)  # random actions violate the limits
    reward = batch["next", GROUP, "reward"].clone()
    trainer = benchmarl_trainer.Trainer.__new__(benchmarl_trainer.Trainer)
    trainer.lagrangian = Lagrangian(CostSettings("magnitude", multiplier=2.0), 3 * 2)
    trainer.collected(batch)
    info = batch["next", GROUP, "info"]
    g = torch.stack([info[f"constraint_{kind}"] for kind in CONSTRAINTS], -1).numpy()
    expected = reward.numpy()[..., 0] - 2.0 * magnitude_cost(g)
    assert np.abs(magnitude_cost(g)).max() > 0
    np.testing.assert_allclose(batch["next", GROUP, "reward"].numpy()[..., 0], expected, rtol=1e-5)
    # the episodes that ended: each copy's first at step 4, with the team's return
    assert trainer.ends == ["max_cycles"] * 3 and trainer.lengths == [4.0] * 3
    team = reward[:, :4, 0, 0].sum(1)
    np.testing.assert_allclose(trainer.returns, team.numpy(), rtol=1e-5)
    assert len(trainer.lagrangian.take_finished()) == 3 * 2  # one per robot


def _cuda_run(tmp_path, device: str | int, robot_steps: int = 64) -> dict:
    settings = RunSettings(
        "short",
        {"max_cycles": 6},
        robot_steps,
        2,
        0,
        tmp_path / "cuda",
        checkpoint_every=0,
        hyperparameters=dict(TINY_HP),
        progress=False,
    )
    out = train("benchmarl", "mappo", settings, backend="cuda", device=device)
    return json.loads((out / "config.json").read_text())


def test_the_cuda_backend_steps_the_copies_there_and_the_checkpoint_plays_on_the_host(
    tmp_path, emulated_xp
):
    config = _cuda_run(tmp_path, "cpu")
    own = config["library_settings"]
    assert own["backend"] == "cuda" and own["task_config"]["backend"] == "cuda"
    assert own["device"] == "cpu" and config["robot_steps"] == 64
    # the recorded evaluation loaded the checkpoint with its task on the CPU backend
    assert config["eval"]["episodes"][0]["episode_steps"] > 0


def test_check_options_refuses_what_the_trainer_cannot_honour():
    args = Namespace(backend="cpu", device=None, dtype="float32")
    bad = {
        "--hp 'experiment.max_n_frames'": {"experiment.max_n_frames": 9},
        "SECTION.KEY": {"lr": 1},
        "has no 'clip_eps'": {"algorithm.clip_eps": 0.1},
    }
    for message, hp in bad.items():
        settings = RunSettings("short", hyperparameters=hp)
        with pytest.raises(ValueError, match=message):
            benchmarl_trainer.check_options(settings, "mappo", args)
    with pytest.raises(ValueError, match="several values"):
        benchmarl_trainer.check_options(RunSettings("random", team_sizes=(2, 3)), "mappo", args)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_on_a_gpu_the_copies_and_the_updates_stay_there(tmp_path):
    pytest.importorskip("cupy")
    config = _cuda_run(tmp_path, 0, robot_steps=640)
    own = config["library_settings"]
    assert own["device"] == "cuda:0" and "gpu" in config["hardware"]
    assert config["eval"]["episodes"][0]["episode_steps"] > 0
