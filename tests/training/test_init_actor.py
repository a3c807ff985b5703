"""Expert-initialized PPO (``--init-actor``): before any update, the PPO policy's
deterministic action is the DAgger clone's on held states (states of a clone rollout)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

import uvms_env
from baselines.loaders.clone_policy import ClonedPolicy
from baselines.loaders.sb3_policy import SB3Policy
from baselines.train import build_parser, settings_from
from uvms_env.policy import AgentSpec

PRIORS = [
    "--env-option", "action_mode=residual", "--env-option", "observation_mode=memory",
    "--env-option", "residual_scale=1.0",
]  # fmt: skip


def _built(tmp_path, extra: list[str]) -> tuple[argparse.Namespace, object]:
    """An initialized model saved before any training step (the trainer's build and save)."""
    from baselines.rl.sb3_trainer import Trainer
    from baselines.runs import Run

    argv = [
        "--library", "sb3", "--scenario", "random", "--env-option", "n_agents=2",
        "--num-envs", "1", "--out", str(tmp_path / "run"), *extra,
    ]  # fmt: skip
    args = build_parser("sb3").parse_args(argv)
    settings = settings_from(args, {"num_envs": 1, "geometry_pool": 16})
    run = Run.start(settings, "sb3", "ppo", argv)
    trainer = Trainer(run, "ppo", args)
    run.write_config(**trainer.build())
    trainer.save(run.folder)
    trainer.close()
    return args, run.folder


def test_the_initialized_actor_acts_as_the_clone(tmp_path):
    _, folder = _built(tmp_path, [*PRIORS, "--init-actor", "dagger:pretrained"])
    env = uvms_env.parallel_env(scenario="random", n_agents=2, seed=31)
    obs, _ = env.reset(seed=31)
    specs = [AgentSpec.from_scenario(env.scenario, i) for i in range(2)]
    clone = [ClonedPolicy(s, ClonedPolicy.locate("dagger", None)) for s in specs]
    ppo = [SB3Policy(s, "ppo", folder) for s in specs]
    gaps = []
    for _ in range(60):  # held states: the clone's own rollout
        actions = {}
        for i, agent in enumerate(env.agents):
            a_clone, a_ppo = clone[i].act(obs[agent]), ppo[i].act(obs[agent])
            gaps.append(np.abs(a_clone - a_ppo).max())
            actions[agent] = a_clone
        obs, *_ = env.step(actions)
    # float32 layers on both sides, the same weights: agreement to rounding
    assert max(gaps) < 1e-4


def test_init_actor_refuses_priors_the_clone_cannot_carry_over(tmp_path):
    with pytest.raises(ValueError, match="action_mode=residual"):
        _built(tmp_path, ["--init-actor", "dagger:pretrained"])
    with pytest.raises(ValueError, match="hold"):
        _built(
            tmp_path,
            [*PRIORS, "--env-option", "hold_stiffness=0.5", "--init-actor", "dagger:pretrained"],
        )


def test_the_critic_warmup_keeps_the_actor_and_trains_the_critic(tmp_path):
    import torch
    from stable_baselines3 import PPO

    from baselines.train import main

    def run(name: str, warmup: int):
        out = tmp_path / name
        main(
            [
                "--library", "sb3", "--scenario", "random", "--env-option", "n_agents=2",
                *PRIORS, "--init-actor", "dagger:pretrained", "--num-envs", "1",
                "--hp", "n_steps=64", "--robot-steps", "256", "--checkpoint-every", "0",
                "--critic-warmup", str(warmup), "--no-progress", "--out", str(out),
                "--eval-max-cycles", "20",
            ]
        )  # fmt: skip
        return PPO.load(out / "model.zip", device="cpu").policy

    _, init = _built(tmp_path, [*PRIORS, "--init-actor", "dagger:pretrained"])
    start = PPO.load(init / "model.zip", device="cpu").policy
    kept, moved = run("warm", 10_000), run("cold", 0)

    def actor(p) -> list[torch.Tensor]:
        return [*p.mlp_extractor.policy_net.parameters(), *p.action_net.parameters(), p.log_std]

    def critic(p) -> list[torch.Tensor]:
        return [*p.mlp_extractor.value_net.parameters(), *p.value_net.parameters()]

    same = lambda a, b: all(torch.equal(x, y) for x, y in zip(a, b, strict=True))  # noqa: E731
    assert same(actor(kept), actor(start))
    assert not same(critic(kept), critic(start))
    assert not same(actor(moved), actor(start))


def test_obs_stats_frozen_keeps_the_clones_statistics_and_moving_moves_them(tmp_path):
    import pickle

    from stable_baselines3.common.running_mean_std import RunningMeanStd

    from baselines.train import main

    def stats(folder) -> tuple[np.ndarray, np.ndarray]:
        with open(folder / "vecnormalize.pkl", "rb") as f:
            rms = pickle.load(f).obs_rms
        assert type(rms) is RunningMeanStd  # saved as SB3's own class, frozen or not
        return rms.mean.copy(), rms.var.copy()

    def run(name: str, extra: list[str]):
        out = tmp_path / name
        main(
            [
                "--library", "sb3", "--scenario", "random", "--env-option", "n_agents=2",
                *PRIORS, "--init-actor", "dagger:pretrained", "--num-envs", "1",
                "--hp", "n_steps=64", "--robot-steps", "256", "--checkpoint-every", "0",
                "--no-progress", "--out", str(out), "--eval-max-cycles", "20", *extra,
            ]
        )  # fmt: skip
        return stats(out)

    _, init = _built(tmp_path, [*PRIORS, "--init-actor", "dagger:pretrained"])
    start = stats(init)
    for frozen in (run("frozen", ["--obs-stats", "frozen"]),
                   run("warm", ["--obs-stats", "warmup", "--critic-warmup", "10000"])):  # fmt: skip
        assert all(np.array_equal(a, b) for a, b in zip(frozen, start, strict=True))
    moving = run("moving", [])
    assert not np.array_equal(moving[0], start[0])
    # after the warm-up they move again: a warm-up shorter than the run
    after = run("after", ["--obs-stats", "warmup", "--critic-warmup", "64"])
    assert not np.array_equal(after[0], start[0])


def test_obs_stats_needs_the_clone_and_its_warmup(tmp_path):
    with pytest.raises(ValueError, match="--init-actor"):
        _built(tmp_path, [*PRIORS, "--obs-stats", "frozen"])
    with pytest.raises(ValueError, match="--critic-warmup"):
        _built(tmp_path, [*PRIORS, "--init-actor", "dagger:pretrained", "--obs-stats", "warmup"])
