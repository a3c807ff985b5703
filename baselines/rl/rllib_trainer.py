"""The Ray RLlib trainer of ``python -m baselines.train`` (new API stack): PPO, one policy
shared by all robots.

    python -m baselines.train --library rllib --algo ppo --scenario random \\
        --env-option n_agents=2 --num-env-runners 2 [--address HEAD:6379] --out runs/rllib_ppo

``--num-env-runners`` actors collect episodes (``baselines.rl.rllib_env``); without
``--address`` a local Ray starts. The run folder also gets ``checkpoints/robot_steps_S``
(with the multiplier in force beside each, under a cost) and the final ``checkpoint/``;
``--resume RUN`` restores the newer of the final and the newest numbered one, so a killed
run goes on from its last checkpoint (``find_resume``). Reference: docs/scale-out.md.

May import: ray (inside functions), torch, ``baselines.runs``, ``baselines.lagrangian``,
``baselines.registry``, ``baselines.command_line`` (the flags' types),
``baselines.loaders.rllib_policy`` (the checkpoint's layout), ``baselines.rl.rllib_env``
and ``uvms_env``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
from pathlib import Path
from typing import Any

from baselines.command_line import non_negative_int, positive_int
from baselines.lagrangian import Lagrangian
from baselines.loaders.rllib_policy import POLICY_ID, RLlibPolicy
from baselines.registry import LIBRARIES
from baselines.runs import Run, seeded_pool, write_json

os.environ.setdefault("OMP_NUM_THREADS", "1")

ALGOS = LIBRARIES["rllib"].algos
# SB3 PPO's defaults where RLlib has the same knob (gamma, lambda, lr, clip, epochs,
# minibatch), the SB3 trainer's 256-step rollout per robot sub-env times 4 copies x 2
# robots = 2,048 robot-steps, which with N = 2 is 1,024 env steps (RLlib counts env steps).
HYPERPARAMETERS: dict[str, Any] = {
    "train_batch_size_per_learner": 1024,
    "minibatch_size": 256,
    "num_epochs": 10,
    "lr": 3e-4,
    "gamma": 0.99,
    "lambda_": 0.95,
    "clip_param": 0.2,
    "entropy_coeff": 0.0,
    "vf_loss_coeff": 0.5,
}
# The SB3 trainer's network: two tanh layers of 64, separate policy and value nets.
MODEL = {"fcnet_hiddens": [64, 64], "fcnet_activation": "tanh", "vf_share_layers": False}
# Seeded families: the pool's P seeds are dealt round-robin over the K env copies
# (``uvms_env.vector.seeding``): a copy meets P / K of them (K dividing P). The single
# env builds a geometry with an IPOPT solve and keeps 32 in memory: the default pool is
# 32 K (None below), 32 per copy; a larger one rebuilds a geometry every episode (the
# batched env of the other trainers copies its 1,024 from the disk bank instead).
GEOMETRIES_PER_COPY = 32
# Env copies per runner (``--num-envs``), stepped together with one forward pass: 4
# beat 1 and matched 8, which builds twice the geometries (figures in the docs).
DEFAULTS: dict[str, Any] = {"num_envs": 4, "geometry_pool": None}
# One team size per run: every env copy of every runner plays the run's overrides (the
# several-size trainers deal their copies into groups; ``rllib_env`` has no such groups).
SEVERAL_TEAM_SIZES = False


def build_config(
    settings: Any,
    args: argparse.Namespace,
    seed: int,
    geometry_pool: int | None,
    hyperparameters: dict[str, Any],
):
    """RLlib's PPO config of a run's ``settings`` (``baselines.runs.RunSettings``) and
    RLlib options ``args``: one ``RLModule`` (``POLICY_ID``) for every robot, its env copies
    seeded from ``seed``."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.tune.registry import register_env

    from baselines.rl.rllib_env import ENV_NAME, make_env

    register_env(ENV_NAME, make_env)
    env_config = {
        "scenario": settings.scenario,
        "overrides": settings.env_options(),
        "seed": seed,
        "geometry_pool": geometry_pool,
        "envs_per_runner": settings.num_envs,
        "num_env_runners": args.num_env_runners,
        "cost": settings.cost.as_dict() if settings.cost is not None else None,
    }
    fragment = args.rollout_fragment_length
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_config, clip_actions=True)
        .env_runners(
            num_env_runners=args.num_env_runners,
            num_envs_per_env_runner=settings.num_envs,
            num_cpus_per_env_runner=1,
            rollout_fragment_length=fragment if fragment == "auto" else int(fragment),
        )
        .multi_agent(policies={POLICY_ID}, policy_mapping_fn=_shared)
        .rl_module(
            rl_module_spec=MultiRLModuleSpec(
                rl_module_specs={POLICY_ID: RLModuleSpec(model_config=DefaultModelConfig(**MODEL))}
            )
        )
        .training(**hyperparameters)
        .learners(num_learners=0)
        .debugging(seed=seed, log_level="ERROR")
    )


def _shared(agent_id: Any, *args: Any, **kwargs: Any) -> str:
    return POLICY_ID


OPTIONS_NOTE = (
    "--num-envs counts the env copies of each env runner; --hp KEY=JSON: an argument of "
    "PPOConfig.training(); --cost: every env runner's envs get the multiplier after each "
    "iteration's dual step"
)


def fragment_length(text: str) -> str:
    """``--rollout-fragment-length``: ``auto`` or a positive number of env steps."""
    return text if text == "auto" else str(positive_int(text))


def add_arguments(g: Any) -> None:
    """The RLlib trainer's own options (``--num-envs``: env copies per runner)."""
    g.add_argument(
        "--num-env-runners", type=non_negative_int, default=2, help="RLlib env runner actors"
    )
    g.add_argument("--address", default=None, help="Ray cluster to join (default: local Ray)")
    g.add_argument("--num-cpus", type=positive_int, default=None, help="local Ray only")
    g.add_argument("--iterations", type=positive_int, default=None, help="stop after this many too")
    g.add_argument(
        "--rollout-fragment-length",
        type=fragment_length,
        default="auto",
        help="env steps per runner request (auto or a number)",
    )


def check_options(settings: Any, algo: str, args: argparse.Namespace) -> None:
    """ValueError naming the option where this trainer cannot honour ``settings``
    (``baselines.runs.RunSettings``) or its own options ``args``: before any work (Ray is
    imported only to check ``--hp``)."""
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r} for RLlib; expected one of {ALGOS}")
    if args.address and args.num_cpus is not None:
        raise ValueError("--num-cpus sizes a local Ray: a cluster (--address) has its own")
    if settings.hyperparameters:
        import inspect

        from baselines.ray_runtime import require_ray

        require_ray()
        from ray.rllib.algorithms.ppo import PPOConfig

        known = sorted(
            {
                name
                for cls in PPOConfig.__mro__
                if "training" in vars(cls)
                for name in inspect.signature(vars(cls)["training"]).parameters
            }
            - {"self", "kwargs"}
        )
        unknown = sorted(set(settings.hyperparameters) - set(known))
        if unknown:
            raise ValueError(
                f"--hp {unknown}: PPOConfig.training() takes none of them; it takes {known}"
            )


def iteration_robot_steps(result: dict[str, Any]) -> int:
    """Robot-steps sampled in the iteration, from RLlib's result."""
    runners = result.get("env_runners", {})
    agent_steps = runners.get("num_agent_steps_sampled") or 0
    if isinstance(agent_steps, dict):  # per agent id in multi-agent runs
        agent_steps = sum(agent_steps.values())
    return int(agent_steps)


CHECKPOINTS, NUMBERED = "checkpoints", "robot_steps_"  # checkpoints/robot_steps_<S>


def find_resume(path: Path | str, recorded: dict[str, Any]) -> tuple[Path, int, float | None]:
    """(checkpoint, robot-steps done, multiplier or None) that ``--resume PATH`` continues:
    a run folder's final ``checkpoint/``, or its newest numbered checkpoint where it has no
    final one or that one is newer (a killed run), or a checkpoint folder itself. A
    numbered checkpoint's robot-steps are in its name and its multiplier beside it; the
    final one's in the run's config.json (``recorded``)."""
    path = Path(path)
    numbered = sorted(
        (p for p in path.glob(f"{CHECKPOINTS}/{NUMBERED}*") if RLlibPolicy.accepts(p)),
        key=lambda p: int(p.name.removeprefix(NUMBERED)),
    )
    final = path / RLlibPolicy.SAVED
    if numbered and (
        not RLlibPolicy.accepts(final) or numbered[-1].stat().st_mtime > final.stat().st_mtime
    ):
        checkpoint = numbered[-1]
    else:
        checkpoint = RLlibPolicy.find(path)  # ValueError naming what it expected
    if checkpoint.parent.name == CHECKPOINTS and checkpoint.name.startswith(NUMBERED):
        saved = checkpoint.with_suffix(".json")
        multiplier = json.loads(saved.read_text())["multiplier"] if saved.is_file() else None
        return checkpoint, int(checkpoint.name.removeprefix(NUMBERED)), multiplier
    final_multiplier = (recorded.get("cost") or {}).get("final_multiplier")
    return checkpoint, int(recorded.get("robot_steps", 0)), final_multiplier


class Trainer:
    """RLlib's PPO under a ``baselines.runs.Run`` (``baselines.runs.Trainer``)."""

    def __init__(self, run: Run, algo: str, args: argparse.Namespace) -> None:
        check_options(run.settings, algo, args)
        self.run, self.args = run, args
        self.algorithm: Any = None
        # the driver's side of PPO-Lagrangian: the multiplier and its dual step
        cost = run.settings.cost
        self.lagrangian = Lagrangian(cost, robots=1) if cost is not None else None
        self.robot_steps = 0

    def build(self) -> dict[str, Any]:
        from baselines.ray_runtime import init_ray, require_ray

        require_ray()
        import torch

        torch.set_num_threads(1)  # the learner shares the machine with the env runners
        s, a = self.run.settings, self.args
        copies = max(1, a.num_env_runners) * s.num_envs
        size = s.geometry_pool if s.geometry_pool is not None else GEOMETRIES_PER_COPY * copies
        pool = seeded_pool(s.scenario, s.overrides, size)
        hp = {**HYPERPARAMETERS, **s.hyperparameters}
        init_ray(a.address, a.num_cpus if a.num_cpus is not None else max(2, a.num_env_runners))
        import ray

        self.algorithm = build_config(s, a, self.run.env_seed, pool, hp).build_algo()
        if s.resume is not None:
            checkpoint, self.robot_steps, multiplier = find_resume(s.resume, self.run.previous)
            self.algorithm.restore_from_path(str(checkpoint.resolve()))
            if self.lagrangian is not None and multiplier is not None:
                self.lagrangian.multiplier = multiplier
            print(f"resuming {checkpoint} at {self.robot_steps} robot-steps")
        if self.lagrangian is not None:  # the runners' envs may come from the checkpoint
            self.broadcast_multiplier()
        return {
            "num_env_runners": a.num_env_runners,
            "geometry_pool": pool,
            "hyperparameters": hp,
            "model": MODEL,
            "policy_id": POLICY_ID,
            "iterations": a.iterations,
            "ray_address": a.address,
            "ray_version": ray.__version__,
            "cluster_cpus": ray.cluster_resources().get("CPU"),
            "torch_threads": torch.get_num_threads(),
        }

    def learn(self) -> int:
        budget, limit = self.run.settings.robot_steps, self.args.iterations
        # the runners' envs are built: stepping starts (an iteration samples as many
        # robot-steps as its episodes give, so the end is not known in advance)
        self.run.begin()
        iteration = 0
        while self.robot_steps < budget and (limit is None or iteration < limit):
            self.robot_steps += iteration_robot_steps(self.algorithm.train())
            iteration += 1
            returns, lengths = self.episodes()
            run, steps = self.run, self.robot_steps
            run.iteration(steps, returns=returns, lengths=lengths, **self.dual_step())
            with run.apart():
                if run.due("checkpoint_every", steps):
                    self.checkpoint(steps)
                if run.due("eval_every", steps):
                    self.save(run.snapshot)
                    run.evaluate_snapshot(steps)
        self.iterations_done = iteration
        return self.robot_steps

    def episodes(self) -> tuple[list[float], list[float]]:
        """The team returns (unpenalized) and lengths of the training episodes every env
        runner ended in the iteration, as the other trainers record them (RLlib's own
        means are smoothed over recent episodes and sum the robots' penalized rewards)."""
        ended = [e for part in self._on_envs("take_episodes") for e in part]
        return [float(r) for r, _ in ended], [float(n) for _, n in ended]

    def dual_step(self) -> dict[str, Any]:
        """PPO-Lagrangian after an iteration: the episode costs from every env runner, the
        dual step, the new multiplier on every runner's envs; the progress row's cost and
        multiplier ({} without a cost)."""
        if self.lagrangian is None:
            return {}
        for costs in self._on_envs("take_episode_costs"):
            self.lagrangian.add(costs)
        episode_cost = self.lagrangian.end_rollout()
        self.broadcast_multiplier()
        return {"episode_cost": episode_cost, "multiplier": self.lagrangian.multiplier}

    def broadcast_multiplier(self) -> None:
        """Sets the multiplier on every env of every env runner."""
        assert self.lagrangian is not None
        self._on_envs("set_multiplier", self.lagrangian.multiplier)

    def _on_envs(self, method: str, *args: Any) -> list[list[Any]]:
        """``method`` on every env of every env runner (``rllib_env.each_env``): a list
        per runner."""
        from baselines.rl.rllib_env import each_env

        call = functools.partial(each_env, method=method, args=args)
        return self.algorithm.env_runner_group.foreach_env_runner(call)

    def save(self, folder: Path) -> None:
        target = folder if folder != self.run.folder else folder / "checkpoint"
        self.algorithm.save_to_path(str(target.resolve()))

    def checkpoint(self, robot_steps: int) -> None:
        """A numbered checkpoint under the run folder (``learn``, every
        ``--checkpoint-every``), and the multiplier in force beside it (``find_resume``)."""
        folder = self.run.folder / CHECKPOINTS / f"{NUMBERED}{robot_steps}"
        self.algorithm.save_to_path(str(folder.resolve()))
        if self.lagrangian is not None:
            write_json(folder.with_suffix(".json"), {"multiplier": self.lagrangian.multiplier})

    def results(self) -> dict[str, Any]:
        return {"iterations_done": getattr(self, "iterations_done", 0)}

    def close(self) -> None:
        if self.algorithm is not None:
            self.algorithm.stop()
            self.algorithm = None
