"""Train an RL baseline with stable-baselines3, one policy shared by all robots.

    python -m baselines.train --algo ppo --scenario short --total-timesteps 200000 \\
        --n-envs 4 --seed 0 --out runs/ppo

Every robot of every env copy is a sub-environment, so one policy learns from all robots'
local observations. By default the copies are one batched ``uvms_env.vector.VectorEnv``
(``--vec-env vector``: ``VectorVecEnv``, float32, each episode of a seeded family on one of
``--geometry-pool`` geometries); ``--vec-env single`` steps one ``parallel_env`` per copy
(``ParallelVecEnv``, every episode a new geometry). Observations and rewards are normalized
(``VecNormalize``, saved with the model). The run folder gets ``model.zip``,
``vecnormalize.pkl``, ``config.json``, checkpoints, tensorboard logs, ``progress.csv``
and periodic evaluations through ``baselines.evaluate`` (``evaluations.csv``).
``--resume RUN`` continues a run from its last save.

Constraint-aware training (``baselines.rl.lagrangian``): ``--cost magnitude`` (or
``count``) subtracts lambda times each robot's own constraint cost from its reward;
``--multiplier-lr`` > 0 makes lambda a Lagrange multiplier for ``--cost-limit`` per
episode (PPO-Lagrangian), 0 a fixed penalty ``--cost-weight``. Priors are environment
options: ``--env-option action_mode=residual --env-option observation_mode=features``.
Smooth exploration: SB3's gSDE, ``--hp use_sde=true --hp sde_sample_freq=8``.
``--central-critic``: MAPPO, the critic reads the global state (``baselines.rl.mappo``);
without it, IPPO with parameter sharing.
``--eval-ladder`` evaluates every checkpoint on the task ladder (``LADDER``) instead of
the training scenario alone.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.options import add_option_arguments, key_value_pairs
from baselines.rl.lagrangian import COSTS
from baselines.rl.vec_env import ParallelVecEnv

if TYPE_CHECKING:
    from baselines.rl.lagrangian import CostSettings

ALGO_DEFAULTS: dict[str, dict[str, Any]] = {
    # PPO: SB3 defaults except a smaller rollout per sub-env (many sub-envs) and a
    # small network; on the vector path batch_size scales with the rollout (below).
    # SAC: SB3 defaults except a short warm-up, a replay buffer sized to
    # our budgets and one gradient step per collected robot-step (gradient_steps = the
    # number of sub-environments, set in ``train``).
    "ppo": {"n_steps": 256, "batch_size": 256, "gae_lambda": 0.95, "gamma": 0.99, "ent_coef": 0.0},
    "sac": {
        "learning_starts": 2000,
        "batch_size": 256,
        "gamma": 0.99,
        "train_freq": 1,
        "buffer_size": 50_000,
    },
}
# PPO on the vector path, batch_size not given: n_steps * sub-envs / 32 (32 minibatches per
# epoch, as 256 had at 16 copies), at least 256; the single path keeps 256. With 256 the
# update took 65-78% of the wall time at 64 copies. Measured (64 copies = 128 sub-envs,
# short, 2M robot-steps, reward_weights={"violation": 0.05}, seeds 0 and 1; evaluate
# --episodes 20 --seed 100): batch 256: 6,000-6,300 robot-steps/s, ep_rew_mean >= 50 after
# 1.6-1.7M steps, eval 20/20, return 17; batch 1,024: 10,700-11,400 steps/s, >= 50 after
# 1.1-1.4M, 20/20, return 26-36 (single path, 16 copies: 1,651 steps/s). At 400k steps
# and the default reward nothing learned with either (eval 0/20, final error ~2.3 m).
PPO_MINIBATCHES = 32
PPO_MIN_BATCH = 256
NET = [64, 64]
# PPO starts with action std exp(-1) ~ 0.37 instead of 1: with std 1 nearly every step
# violates the joint and vehicle speed limits and the penalties swamp the progress term.
POLICY_KWARGS: dict[str, dict[str, Any]] = {"ppo": {"log_std_init": -1.0}, "sac": {}}
# Training drops the internal-wrench metric (~6% of a step); it changes no observation,
# reward or dynamics.
TRAIN_ENV_DEFAULTS: dict[str, Any] = {"internal_wrench_every": 0}
EVAL_RECORD_EPISODES = 2  # the per-episode evaluation recorded in eval.json
VEC_ENVS = ("vector", "single")
DTYPES = ("float32", "float64")
# float32: the batched step of "short" is 1.3x (16 copies) to 1.8x (64) faster than float64
# on this machine, neither precision refused a step in 64 copies x 600 steps of random
# inputs up to saturation, and float32's deviation (~1e-4 of the state after 100
# saturated periods, README) is far below a stochastic policy's own noise. Evaluation
# stays on the float64 single environments.
DEFAULT_DTYPE = "float32"
# Seeded families: every episode a geometry of the bank's first 1,024 seeds (built once,
# kept on disk): diverse starts without building a geometry inside a step.
DEFAULT_GEOMETRY_POOL = 1024
# One thread for the batched kernels, as for torch: with 2 threads a kernel call waits for
# both cores, so anything else running on this 2-core machine stalls the step 10-17x; on
# an idle machine 2 threads saved 20% of the env time and lost more in the PPO update.
DEFAULT_ENV_THREADS = 1
# The task ladder, easiest first: (scenario, overrides) per rung.
LADDER: dict[str, tuple[str, dict[str, Any]]] = {
    "short": ("short", {}),
    "random_n2": ("random", {"n_agents": 2}),
    "paper": ("paper", {}),
    "random_n3": ("random", {"n_agents": 3}),
}


def env_settings(
    scenario: str,
    vec_env: str = "vector",
    dtype: str = DEFAULT_DTYPE,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    env_threads: int | None = DEFAULT_ENV_THREADS,
    overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The environment settings a run uses (recorded in config.json): the batched path's
    ``dtype``, ``geometry_pool`` (seeded families only, else None) and ``env_threads``;
    the single path has none of them (None)."""
    if vec_env not in VEC_ENVS:
        raise ValueError(f"unknown vec_env {vec_env!r}; expected one of {VEC_ENVS}")
    if vec_env == "single":
        return {"vec_env": "single", "dtype": None, "geometry_pool": None, "env_threads": None}
    if dtype not in DTYPES:
        raise ValueError(f"unknown dtype {dtype!r}; expected one of {DTYPES}")
    from uvms_env.vector.bank import SEEDED_FAMILIES

    seeded = scenario in SEEDED_FAMILIES and (overrides or {}).get("reseed_geometry", True)
    return {
        "vec_env": "vector",
        "dtype": dtype,
        "geometry_pool": geometry_pool if seeded and geometry_pool else None,
        "env_threads": env_threads,
    }


def make_vec_env(
    scenario: str,
    n_envs: int,
    seed: int,
    overrides: dict[str, Any],
    vec_env: str = "vector",
    dtype: str = DEFAULT_DTYPE,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    env_threads: int | None = DEFAULT_ENV_THREADS,
    cost: CostSettings | None = None,
    central_critic: bool = False,
):
    """``VecMonitor`` (over ``CostPenalty`` with ``cost``) over ``n_envs`` env copies as
    ``n_envs * N`` robot sub-environments:
    one ``VectorEnv`` (``vec_env="vector"``: in ``dtype``, on ``env_threads`` threads, None:
    all cores; seeded families: episodes on the first ``geometry_pool`` bank geometries,
    0 or None: each copy keeps its first) or ``n_envs`` ``parallel_env`` (``"single"``,
    which ignores the other three)."""
    from stable_baselines3.common.vec_env import VecMonitor

    kwargs = {**TRAIN_ENV_DEFAULTS, **overrides}
    settings = env_settings(scenario, vec_env, dtype, geometry_pool, env_threads, overrides)
    if settings["vec_env"] == "vector":
        from uvms_env.vector import VectorEnv
        from uvms_env.vector.sb3 import VectorVecEnv

        if settings["geometry_pool"] is not None:
            kwargs["geometry_pool"] = settings["geometry_pool"]
        venv = VectorVecEnv(
            VectorEnv(
                scenario,
                num_envs=n_envs,
                dtype=settings["dtype"],
                threads=settings["env_threads"],
                **kwargs,
            ),
            seed=seed,
        )
    else:
        import uvms_env

        def factory(k: int):
            return uvms_env.parallel_env(scenario=scenario, seed=seed + k, **kwargs)

        venv = ParallelVecEnv(factory, n_envs, seed=seed)
    if central_critic:
        from baselines.rl.mappo import CentralStateVecEnv

        venv = CentralStateVecEnv(venv)
    if cost is not None:
        from baselines.rl.lagrangian import CostPenalty

        venv = CostPenalty(venv, cost)
    # VecMonitor: raw (unnormalized) episode returns and lengths -> rollout/ep_rew_mean.
    return VecMonitor(venv)


def find_resume(path: Path) -> tuple[Path, Path, Path | None]:
    """(model.zip, vecnormalize.pkl, replay buffer or None) to resume from ``path``: a run
    folder (its ``model.zip``, or its newest checkpoint when it has none or the
    checkpoint is newer) or a checkpoint ``.zip``."""
    path = Path(path)
    if path.is_file():
        model = path
    else:
        candidates = sorted(
            (path / "checkpoints").glob("rl_model_*_steps.zip"), key=_checkpoint_steps
        )
        model = candidates[-1] if candidates else path / "model.zip"
        final = path / "model.zip"
        if final.exists() and (not candidates or final.stat().st_mtime >= model.stat().st_mtime):
            model = final
    if not model.exists():
        raise FileNotFoundError(f"nothing to resume at {path}")
    if model.parent.name == "checkpoints":
        steps = _checkpoint_steps(model)
        norm = model.parent / f"rl_model_vecnormalize_{steps}_steps.pkl"
        buffer = model.parent / f"rl_model_replay_buffer_{steps}_steps.pkl"
    else:
        norm = model.parent / "vecnormalize.pkl"
        buffer = model.parent / "replay_buffer.pkl"
    if not norm.exists():
        raise FileNotFoundError(f"no VecNormalize statistics {norm} next to {model}")
    return model, norm, buffer if buffer.exists() else None


def _checkpoint_steps(path: Path) -> int:
    return int(path.stem.split("_")[-2])


def train(
    algo: str,
    scenario: str,
    total_timesteps: int,
    n_envs: int,
    seed: int,
    out: Path,
    resume: Path | None = None,
    eval_every: int = 0,
    eval_episodes: int = 5,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
    hyperparameters: dict[str, Any] | None = None,
    checkpoint_every: int = 50_000,
    record_eval: bool = True,
    vec_env: str = "vector",
    dtype: str = DEFAULT_DTYPE,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    env_threads: int | None = DEFAULT_ENV_THREADS,
    cost: CostSettings | None = None,
    eval_ladder: bool = False,
    central_critic: bool = False,
) -> Path:
    """Train (or continue) until ``total_timesteps`` robot-steps in all; save; return the
    run folder. With ``resume``, the model, its statistics (and SAC's replay buffer) are
    loaded from there and ``total_timesteps`` counts the steps already done. ``vec_env``,
    ``dtype``, ``geometry_pool``, ``env_threads``, ``cost``: see ``make_vec_env``; a
    resumed run keeps its multiplier. ``eval_ladder``: evaluate on every rung of
    ``LADDER``. ``central_critic`` (PPO, vector path): MAPPO (``baselines.rl.mappo``)."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    if algo not in ALGO_DEFAULTS:
        raise ValueError(f"unknown algorithm {algo!r}; expected ppo or sac")
    if central_critic and (algo != "ppo" or vec_env != "vector"):
        raise ValueError("a central critic (MAPPO) needs --algo ppo on the vector env")
    overrides = dict(overrides or {})
    hp = {**ALGO_DEFAULTS[algo], **(hyperparameters or {})}
    # ``--hp policy_kwargs={...}`` adds to the defaults (e.g. log_std_init) instead of
    # replacing them; a resumed model keeps its own.
    policy_extra = hp.pop("policy_kwargs", None) or {}
    if not isinstance(policy_extra, dict):
        raise ValueError(f"policy_kwargs must be a JSON object, got {policy_extra!r}")
    chosen_policy_kwargs = {**POLICY_KWARGS[algo], **policy_extra}
    env: dict[str, Any] = {
        "vec_env": vec_env,
        "dtype": dtype,
        "geometry_pool": geometry_pool,
        "env_threads": env_threads,
    }
    settings = env_settings(scenario, overrides=overrides, **env)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    previous: dict[str, Any] = {}
    if resume is not None:
        model_path, norm_path, buffer_path = find_resume(Path(resume))
        old_config = Path(resume if Path(resume).is_dir() else model_path.parent) / "config.json"
        if not old_config.exists():
            old_config = model_path.parent.parent / "config.json"
        if old_config.exists():
            previous = json.loads(old_config.read_text())
        # New episode seeds, so a resumed run does not replay the first episodes.
        if cost is not None and previous.get("cost"):
            cost.multiplier = previous["cost"].get("final_multiplier", cost.multiplier)
        venv = make_vec_env(
            scenario,
            n_envs,
            seed + 1_000_003 * (1 + previous.get("resumes", 0)),
            overrides,
            **env,
            cost=cost,
            central_critic=central_critic,
        )
        venv = VecNormalize.load(str(norm_path), venv)
        venv.training = True
        model = cls.load(model_path, env=venv, device="cpu")
        if buffer_path is not None and hasattr(model, "load_replay_buffer"):
            model.load_replay_buffer(buffer_path)
        if algo == "sac":
            hp["gradient_steps"] = model.gradient_steps
        reset = False
        print(f"resuming {model_path} at {model.num_timesteps} timesteps")
    else:
        venv = VecNormalize(
            make_vec_env(
                scenario, n_envs, seed, overrides, **env, cost=cost, central_critic=central_critic
            ),
            clip_obs=10.0,
        )
        if algo == "sac":
            hp.setdefault("gradient_steps", venv.num_envs)
        if algo == "ppo" and vec_env == "vector" and "batch_size" not in (hyperparameters or {}):
            rollout = hp["n_steps"] * venv.num_envs
            hp["batch_size"] = max(PPO_MIN_BATCH, rollout // PPO_MINIBATCHES)
        policy: Any = "MlpPolicy"
        policy_kwargs = {"net_arch": NET, **chosen_policy_kwargs}
        if central_critic:
            from baselines.rl.mappo import CentralCriticPolicy, CentralStateVecEnv

            policy = CentralCriticPolicy
            policy_kwargs["local_dim"] = _find_layer(venv, CentralStateVecEnv).local_dim
        model = cls(
            policy,
            venv,
            seed=seed,
            device="cpu",
            policy_kwargs=policy_kwargs,
            verbose=0,
            **hp,
        )
        reset = True
    if algo == "ppo":
        hp["batch_size"] = model.batch_size  # the one used (a resumed model keeps its own)
    _keep_old_progress(out)
    model.set_logger(configure(str(out), ["csv", "tensorboard"]))
    config = {
        "algo": algo,
        "scenario": scenario,
        "total_timesteps": total_timesteps,
        "n_envs": n_envs,
        "robot_sub_envs": venv.num_envs,
        "seed": seed,
        "overrides": overrides,
        **settings,
        "env_defaults": TRAIN_ENV_DEFAULTS,
        "hyperparameters": hp,
        "net_arch": NET,
        "policy_kwargs": chosen_policy_kwargs,
        "resumes": previous.get("resumes", -1) + 1 if resume is not None else 0,
        "torch_threads": torch.get_num_threads(),
        "cost": cost.as_dict() if cost is not None else None,
        "central_critic": central_critic,
        "hardware": _hardware(),
    }
    _write_json(out / "config.json", config)
    callbacks: list[Any] = [
        CheckpointCallback(
            save_freq=max(1, checkpoint_every // venv.num_envs),
            save_path=str(out / "checkpoints"),
            save_vecnormalize=True,
            save_replay_buffer=algo == "sac",
        )
    ]
    from baselines.rl.lagrangian import CostPenalty, MultiplierCallback

    penalty = _find_layer(venv, CostPenalty)
    if penalty is not None:
        callbacks.append(MultiplierCallback(penalty))
    if eval_every > 0:
        rungs = LADDER if eval_ladder else {scenario: (scenario, _rung_overrides(overrides))}
        callbacks.append(_EvalCallback(algo, out, rungs, eval_every, eval_episodes, seed))
    remaining = max(0, total_timesteps - (0 if reset else model.num_timesteps))
    start = time.perf_counter()
    model.learn(
        total_timesteps=remaining,
        callback=CallbackList(callbacks),
        reset_num_timesteps=reset,
        progress_bar=progress,
    )
    wall = time.perf_counter() - start
    save(model, out)
    if algo == "sac":
        model.save_replay_buffer(out / "replay_buffer.pkl")
    config["wall_time_s"] = round(wall + previous.get("wall_time_s", 0.0), 1)
    config["timesteps_done"] = int(model.num_timesteps)
    config["robot_steps_per_s"] = round(remaining / wall, 1) if wall > 0 else None
    if penalty is not None:
        config["cost"]["final_multiplier"] = penalty.multiplier
    if record_eval:
        # The per-episode result of the saved model on fixed seeds: a regression value
        # produced by running, checked by tests/test_rl.py for the pretrained models.
        config["eval"] = record_evaluation(algo, out, scenario, EVAL_RECORD_EPISODES, seed=0)
    _write_json(out / "config.json", config)
    venv.close()
    return out


def _find_layer(venv: Any, cls: type) -> Any:
    """The wrapper of type ``cls`` inside the VecEnv stack, or None."""
    while venv is not None and not isinstance(venv, cls):
        venv = getattr(venv, "venv", None)
    return venv


def _rung_overrides(overrides: dict[str, Any]) -> dict[str, Any]:
    """The evaluation's scenario overrides from the training's: the team size only (the
    evaluation plays the plain environment; the policy applies its own priors)."""
    return {k: v for k, v in overrides.items() if k == "n_agents"}


def _hardware() -> dict[str, Any]:
    import platform

    from uvms_env.vector.kernels import available_cores

    return {
        "machine": platform.machine(),
        "cores": available_cores(),
    }


def record_evaluation(algo: str, folder: Path, scenario: str, episodes: int, seed: int):
    from baselines.evaluate import evaluate

    rows = evaluate([f"{algo}:{folder}"], [scenario], episodes, seed, 1, progress=False)
    return {
        "scenario": scenario,
        "seed": seed,
        "episodes": [
            {
                "episode": r["episode"],
                "seed": r["seed"],
                "success": bool(r.get("success")),
                "return": r["return"],
                "episode_steps": r.get("episode_steps"),
                "final_pos_error_m": r.get("final_pos_error_m"),
            }
            for r in rows
        ],
    }


def _keep_old_progress(out: Path) -> None:
    """SB3's CSV logger truncates progress.csv: keep a resumed run's earlier part."""
    old = out / "progress.csv"
    if old.exists() and old.stat().st_size > 0:
        k = len(list(out.glob("progress.part*.csv")))
        old.rename(out / f"progress.part{k}.csv")


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, default=float) + "\n")


def save(model, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    model.get_vec_normalize_env().save(str(out / "vecnormalize.pkl"))


def _EvalCallback(
    algo: str,
    out: Path,
    rungs: dict[str, tuple[str, dict[str, Any]]],
    every: int,
    episodes: int,
    seed: int,
):
    """Every ``every`` timesteps: save, then evaluate the saved policy with the shared
    evaluation code on fixed seeds, on each rung (name -> scenario, overrides); appends
    one row per rung to ``evaluations.csv``."""
    from stable_baselines3.common.callbacks import BaseCallback

    from baselines.evaluate import aggregate, evaluate

    columns = (
        "timesteps,rung,success_rate,clean_success_rate,violation_periods,mean_return,"
        "final_pos_error_m,episode_steps,errors\n"
    )

    class EvalCallback(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self._next = every

        def _init_callback(self) -> None:
            # Resumed runs: the next evaluation after the steps already done.
            while self._next <= self.model.num_timesteps:
                self._next += every

        def _on_step(self) -> bool:
            if self.num_timesteps < self._next:
                return True
            self._next += every
            snap = out / "eval_snapshot"
            save(self.model, snap)
            # the policy rebuilds the run's observation and action modes from it
            shutil.copyfile(out / "config.json", snap / "config.json")
            start = time.perf_counter()
            path = out / "evaluations.csv"
            if not path.exists() or not path.read_text().startswith(columns[:20]):
                path.write_text(columns)
            for rung, (scenario, overrides) in rungs.items():
                rows = evaluate(
                    [f"{algo}:{snap}"], [scenario], episodes, seed, 1, overrides, progress=False
                )
                s = aggregate(rows, seed)[0]
                periods = float(np.mean([r["violation_periods"] for r in rows]))
                row = [
                    self.num_timesteps,
                    rung,
                    s["success_rate"],
                    s["clean_success_rate"],
                    periods,
                    s.get("return", np.nan),
                    s.get("final_pos_error_m", np.nan),
                    s.get("episode_steps", np.nan),
                    s["errors"],
                ]
                failed = [r["error"] for r in rows if r["error"]]
                if failed:
                    warnings.warn(
                        f"evaluation on {rung}: {len(failed)} episodes failed: {failed[0]}",
                        stacklevel=1,
                    )
                with open(path, "a") as fh:
                    fh.write(",".join(str(x) for x in row) + "\n")
                self.logger.record(f"eval/{rung}/success_rate", s["success_rate"])
                self.logger.record(f"eval/{rung}/clean_success_rate", s["clean_success_rate"])
                self.logger.record(f"eval/{rung}/violation_periods", periods)
            self.logger.record("eval/seconds", time.perf_counter() - start)
            return True

    return EvalCallback()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m baselines.train",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--algo", choices=sorted(ALGO_DEFAULTS), required=True)
    ap.add_argument("--scenario", default="short", help="short (learning-sized), paper, random")
    ap.add_argument("--total-timesteps", type=int, default=200_000, help="robot-steps")
    ap.add_argument("--n-envs", type=int, default=4, help="env copies (each has N robots)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-every", type=int, default=0, help="timesteps between evaluations")
    ap.add_argument("--eval-episodes", type=int, default=5)
    ap.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="run folder (its model.zip or newest checkpoint) or checkpoint .zip to continue; "
        "--total-timesteps then counts the steps already done",
    )
    add_option_arguments(ap, "SB3 hyperparameter")
    ap.add_argument(
        "--vec-env",
        choices=VEC_ENVS,
        default="vector",
        help="vector: the env copies batched in one VectorEnv; single: one parallel_env each",
    )
    ap.add_argument(
        "--dtype", choices=DTYPES, default=DEFAULT_DTYPE, help="the batched step's precision"
    )
    ap.add_argument(
        "--geometry-pool",
        type=int,
        default=DEFAULT_GEOMETRY_POOL,
        help="seeded families (short, random), vector path: episodes use the geometries of "
        "this many bank seeds (0: each copy keeps its first geometry)",
    )
    ap.add_argument(
        "--env-threads",
        type=int,
        default=DEFAULT_ENV_THREADS,
        help="threads of the batched step (vector path)",
    )
    ap.add_argument(
        "--cost",
        choices=("none", *COSTS),
        default="none",
        help="per-robot constraint cost subtracted from its reward (baselines.rl.lagrangian)",
    )
    ap.add_argument("--cost-weight", type=float, default=0.1, help="starting multiplier")
    ap.add_argument("--cost-limit", type=float, default=0.0, help="cost per episode and robot")
    ap.add_argument(
        "--multiplier-lr", type=float, default=0.0, help="dual step size (0: fixed penalty)"
    )
    ap.add_argument(
        "--central-critic",
        action="store_true",
        help="MAPPO: the critic also reads the global state (PPO, vector env)",
    )
    ap.add_argument(
        "--eval-ladder", action="store_true", help="evaluate on every rung of the task ladder"
    )
    ap.add_argument("--checkpoint-every", type=int, default=50_000, help="timesteps")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--out", type=Path, default=Path("runs/rl"))
    args = ap.parse_args(argv)
    out = train(
        args.algo,
        args.scenario,
        args.total_timesteps,
        args.n_envs,
        args.seed,
        args.out,
        resume=args.resume,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        overrides=key_value_pairs(args.env_option),
        progress=not args.no_progress,
        hyperparameters=key_value_pairs(args.hp),
        checkpoint_every=args.checkpoint_every,
        vec_env=args.vec_env,
        dtype=args.dtype,
        geometry_pool=args.geometry_pool,
        env_threads=args.env_threads,
        cost=_cost(args),
        eval_ladder=args.eval_ladder,
        central_critic=args.central_critic,
    )
    print(f"saved {out / 'model.zip'} and {out / 'vecnormalize.pkl'}")


def _cost(args: argparse.Namespace) -> CostSettings | None:
    if args.cost == "none":
        return None
    from baselines.rl.lagrangian import CostSettings

    return CostSettings(args.cost, args.cost_weight, args.cost_limit, args.multiplier_lr)


if __name__ == "__main__":
    main()
