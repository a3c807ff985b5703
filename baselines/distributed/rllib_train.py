"""Train with Ray RLlib (new API stack), one policy shared by all robots.

    python -m baselines.train --engine rllib --algo ppo --scenario random --n-agents 2 \\
        --num-env-runners 2 [--address HEAD:6379] --out runs/rllib_ppo

RLlib is the distributed engine: ``--num-env-runners`` actors collect episodes, each
stepping ``--num-envs-per-env-runner`` copies of ``uvms_env.parallel_env``
(``baselines.distributed.rllib_env``) together; the learner updates the shared module.
Without ``--address`` a local Ray starts; with it, the run joins that cluster.
Environment options are the SB3 trainer's (``--env-option KEY=JSON``), recorded in
config.json (``overrides``, and with the training defaults ``env_options``): the
periodic evaluation passes the overrides to its environments, the policy loader keeps
``env_options``. The run folder gets ``config.json``, ``progress.csv`` (one row per
iteration), ``checkpoints/iter_K`` every ``--checkpoint-every`` iterations, the final
``checkpoint/``, and with ``--eval-every`` periodic evaluations through
``baselines.evaluate`` (``evaluations.csv``, and ``marl_eval.json`` for marl-eval).

Differences from the SB3 trainer: no observation or reward normalization (RLlib would
keep the statistics in its connectors, which the per-agent policy loader does not run),
and the action spread is RLlib's learned state-dependent log-std.

May import: ray (inside functions), torch, numpy, ``baselines.evaluate``,
``baselines.distributed`` and ``uvms_env``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from pathlib import Path
from typing import Any

from baselines.options import add_option_arguments, key_value_pairs

os.environ.setdefault("OMP_NUM_THREADS", "1")

ALGOS = ("ppo",)
POLICY_ID = "shared"
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
# As the SB3 trainer: training drops the internal-wrench metric (no effect on observations,
# rewards or dynamics).
TRAIN_ENV_DEFAULTS: dict[str, Any] = {"internal_wrench_every": 0}
# Seeded families: geometries per env runner. The single env builds a geometry in ~0.5 s
# and keeps 32 in memory: a larger pool rebuilds one every episode (the SB3 trainer's
# batched env copies its 1,024 from the disk bank instead).
DEFAULT_GEOMETRY_POOL = 32
# Env copies per runner, stepped together with one forward pass: on this 2-core machine
# (random, N = 2, shared with another job) 4 copies gave 815-890 robot-steps/s per
# iteration against 414-553 with 1; 8 gave 825-1,030 but build twice the geometries.
DEFAULT_ENVS_PER_RUNNER = 4
PROGRESS_COLUMNS = (
    "iteration",
    "timesteps",
    "env_steps",
    "episodes",
    "episode_return_mean",
    "episode_len_mean",
    "time_this_iter_s",
    "time_total_s",
    "sampling_s",
    "learner_s",
    "robot_steps_per_s",
)
EVAL_COLUMNS = "timesteps,success_rate,mean_return,final_pos_error_m,episode_steps\n"


def build_config(
    scenario: str,
    overrides: dict[str, Any],
    seed: int,
    num_env_runners: int,
    geometry_pool: int | None,
    hyperparameters: dict[str, Any],
    rollout_fragment_length: int | str = "auto",
    envs_per_runner: int = DEFAULT_ENVS_PER_RUNNER,
):
    """RLlib's PPO config: one ``RLModule`` (``POLICY_ID``) for every robot."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.tune.registry import register_env

    from baselines.distributed.rllib_env import ENV_NAME, make_env

    register_env(ENV_NAME, make_env)
    env_config = {
        "scenario": scenario,
        "overrides": overrides,
        "seed": seed,
        "geometry_pool": geometry_pool,
        "envs_per_runner": envs_per_runner,
    }
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_config, clip_actions=True)
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=envs_per_runner,
            num_cpus_per_env_runner=1,
            rollout_fragment_length=rollout_fragment_length,
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


def progress_row(result: dict[str, Any]) -> dict[str, Any]:
    runners = result.get("env_runners", {})
    timers = result.get("timers", {})
    agent_steps = runners.get("num_agent_steps_sampled_lifetime")
    if isinstance(agent_steps, dict):  # per agent id in multi-agent runs
        agent_steps = sum(agent_steps.values())
    total = float(result.get("time_total_s", 0.0))
    return {
        "iteration": result.get("training_iteration"),
        "timesteps": int(agent_steps or 0),
        "env_steps": runners.get("num_env_steps_sampled_lifetime"),
        "episodes": runners.get("num_episodes_lifetime"),
        "episode_return_mean": runners.get("episode_return_mean"),
        "episode_len_mean": runners.get("episode_len_mean"),
        "time_this_iter_s": result.get("time_this_iter_s"),
        "time_total_s": total,
        # RLlib's timers (smoothed over iterations): sampling vs. the learner's update
        "sampling_s": timers.get("env_runner_sampling_timer"),
        "learner_s": timers.get("learner_update_timer"),
    }


def train(
    algo: str,
    scenario: str,
    total_timesteps: int,
    num_env_runners: int,
    seed: int,
    out: Path,
    address: str | None = None,
    overrides: dict[str, Any] | None = None,
    hyperparameters: dict[str, Any] | None = None,
    iterations: int | None = None,
    checkpoint_every: int = 10,
    eval_every: int = 0,
    eval_episodes: int = 5,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    num_cpus: int | None = None,
    rollout_fragment_length: int | str = "auto",
    envs_per_runner: int = DEFAULT_ENVS_PER_RUNNER,
    progress: bool = True,
) -> Path:
    """Train until ``total_timesteps`` robot-steps (or ``iterations`` iterations, whichever
    comes first); save the final checkpoint in ``out/checkpoint``; return ``out``."""
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r} for RLlib; expected one of {ALGOS}")
    from baselines.distributed.ray_backend import init_ray, require_ray

    require_ray()
    import torch

    from uvms_env.vector.bank import SEEDED_FAMILIES

    torch.set_num_threads(1)  # the learner shares the machine with the env runners
    overrides = dict(overrides or {})
    env_options = {**TRAIN_ENV_DEFAULTS, **overrides}
    seeded = scenario in SEEDED_FAMILIES and overrides.get("reseed_geometry", True)
    pool = geometry_pool if seeded and geometry_pool else None
    hp = {**HYPERPARAMETERS, **(hyperparameters or {})}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    init_ray(address, num_cpus if num_cpus is not None else max(2, num_env_runners))
    import ray

    config = build_config(
        scenario,
        env_options,
        seed,
        num_env_runners,
        pool,
        hp,
        rollout_fragment_length,
        envs_per_runner,
    )
    algorithm = config.build_algo()
    record: dict[str, Any] = {
        "engine": "rllib",
        "algo": algo,
        "scenario": scenario,
        "total_timesteps": total_timesteps,
        "iterations": iterations,
        "num_env_runners": num_env_runners,
        "envs_per_runner": envs_per_runner,
        "seed": seed,
        "overrides": overrides,
        "env_defaults": TRAIN_ENV_DEFAULTS,
        "env_options": env_options,
        "geometry_pool": pool,
        "hyperparameters": hp,
        "model": MODEL,
        "policy_id": POLICY_ID,
        "ray_address": address,
        "ray_version": ray.__version__,
        "cluster_cpus": ray.cluster_resources().get("CPU"),
        "torch_threads": torch.get_num_threads(),
    }
    _write_json(out / "config.json", record)
    start = time.perf_counter()
    next_eval = eval_every
    iteration, timesteps = 0, 0
    with open(out / "progress.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=PROGRESS_COLUMNS)
        writer.writeheader()
        while timesteps < total_timesteps and (iterations is None or iteration < iterations):
            tick = time.perf_counter()
            result = algorithm.train()
            row = progress_row(result)
            steps_now = row["timesteps"] - timesteps
            row["robot_steps_per_s"] = round(steps_now / max(1e-9, time.perf_counter() - tick), 1)
            iteration, timesteps = int(row["iteration"] or iteration + 1), row["timesteps"]
            writer.writerow(row)
            fh.flush()
            if progress:
                print(
                    f"iter {iteration}: {timesteps} robot-steps, return "
                    f"{row['episode_return_mean']}, {row['robot_steps_per_s']} robot-steps/s"
                )
            if checkpoint_every > 0 and iteration % checkpoint_every == 0:
                algorithm.save_to_path(str((out / "checkpoints" / f"iter_{iteration}").resolve()))
            if eval_every > 0 and timesteps >= next_eval:
                next_eval += eval_every * (1 + (timesteps - next_eval) // eval_every)
                snap = (out / "eval_snapshot").resolve()
                algorithm.save_to_path(str(snap))
                _evaluate(snap, out, scenario, overrides, eval_episodes, seed, timesteps, start)
    wall = time.perf_counter() - start
    final = (out / "checkpoint").resolve()
    algorithm.save_to_path(str(final))
    algorithm.stop()
    record.update(
        wall_time_s=round(wall, 1),
        timesteps_done=timesteps,
        iterations_done=iteration,
        robot_steps_per_s=round(timesteps / max(wall, 1e-9), 1),
    )
    _write_json(out / "config.json", record)
    return out


def _evaluate(
    snapshot: Path,
    out: Path,
    scenario: str,
    overrides: dict[str, Any],
    episodes: int,
    seed: int,
    timesteps: int,
    start: float,
) -> None:
    """The saved policy on fixed seeds through the shared evaluation code, in this
    process: evaluations.csv (the SB3 trainer's columns) and one marl-eval step."""
    import numpy as np

    from baselines.distributed import marl_eval
    from baselines.evaluate import aggregate, evaluate

    rows = evaluate([f"rllib:{snapshot}"], [scenario], episodes, seed, 1, overrides, progress=False)
    s = aggregate(rows, seed)[0]
    path = out / "evaluations.csv"
    if not path.exists():
        path.write_text(EVAL_COLUMNS)
    values = [
        timesteps,
        s["success_rate"],
        s.get("return", np.nan),
        s.get("final_pos_error_m", np.nan),
        s.get("episode_steps", np.nan),
    ]
    with open(path, "a") as fh:
        fh.write(",".join(str(x) for x in values) + "\n")
    for row in rows:  # one algorithm name per run in marl-eval, not the snapshot's path
        row["policy"] = f"rllib_ppo:{out.name}"
    marl_eval.write(
        out / "marl_eval.json",
        rows,
        seed,
        step_count=timesteps,
        elapsed_time=time.perf_counter() - start,
        overrides=overrides,
    )


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, default=str) + "\n")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m baselines.train --engine rllib",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--algo", choices=ALGOS, required=True)
    ap.add_argument("--scenario", default="short", help="short (learning-sized), paper, random")
    ap.add_argument("--n-agents", type=int, default=None, help="random family: team size")
    ap.add_argument("--total-timesteps", type=int, default=200_000, help="robot-steps")
    ap.add_argument("--iterations", type=int, default=None, help="stop after this many too")
    ap.add_argument("--num-env-runners", type=int, default=2, help="RLlib env runner actors")
    ap.add_argument(
        "--num-envs-per-env-runner",
        type=int,
        default=DEFAULT_ENVS_PER_RUNNER,
        help="env copies each runner steps together (one batched forward pass)",
    )
    ap.add_argument("--address", default=None, help="Ray cluster to join (default: local Ray)")
    ap.add_argument("--num-cpus", type=int, default=None, help="local Ray only")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-every", type=int, default=0, help="robot-steps between evaluations")
    ap.add_argument("--eval-episodes", type=int, default=5)
    ap.add_argument("--checkpoint-every", type=int, default=10, help="iterations")
    ap.add_argument(
        "--geometry-pool",
        type=int,
        default=DEFAULT_GEOMETRY_POOL,
        help="seeded families: geometries per env runner (0: every episode a new one)",
    )
    ap.add_argument(
        "--rollout-fragment-length", default="auto", help="env steps per runner request"
    )
    add_option_arguments(ap, "PPOConfig.training()")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("runs/rllib_ppo"))
    args = ap.parse_args(argv)
    overrides = key_value_pairs(args.env_option)
    if args.n_agents is not None:
        overrides["n_agents"] = args.n_agents
    fragment = args.rollout_fragment_length
    out = train(
        args.algo,
        args.scenario,
        args.total_timesteps,
        args.num_env_runners,
        args.seed,
        args.out,
        address=args.address,
        overrides=overrides,
        hyperparameters=key_value_pairs(args.hp),
        iterations=args.iterations,
        checkpoint_every=args.checkpoint_every,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        geometry_pool=args.geometry_pool,
        num_cpus=args.num_cpus,
        rollout_fragment_length=fragment if fragment == "auto" else int(fragment),
        envs_per_runner=args.num_envs_per_env_runner,
        progress=not args.no_progress,
    )
    print(f"saved {out / 'checkpoint'}")


if __name__ == "__main__":
    main()
