"""Train an RL baseline with stable-baselines3, one policy shared by all robots.

    python -m baselines.train --algo ppo --scenario short --total-timesteps 200000 \\
        --n-envs 4 --seed 0 --out runs/ppo

Every robot of every env copy is a sub-environment (``ParallelVecEnv``), so one policy
learns from all robots' local observations. Observations and rewards are normalized
(``VecNormalize``, saved with the model). The run folder gets ``model.zip``,
``vecnormalize.pkl``, ``config.json``, checkpoints, tensorboard logs, ``progress.csv``
and periodic evaluations through ``baselines.evaluate`` (``evaluations.csv``).
``--resume RUN`` continues a run from its last save.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.rl.vec_env import ParallelVecEnv

ALGO_DEFAULTS: dict[str, dict[str, Any]] = {
    # PPO: SB3 defaults except a smaller rollout per sub-env (many sub-envs) and a
    # small network; SAC: SB3 defaults with a short warm-up.
    "ppo": {"n_steps": 256, "batch_size": 256, "gae_lambda": 0.95, "gamma": 0.99, "ent_coef": 0.0},
    "sac": {"learning_starts": 2000, "batch_size": 256, "gamma": 0.99, "train_freq": 1},
}
NET = [64, 64]


def make_vec_env(scenario: str, n_envs: int, seed: int, overrides: dict[str, Any]):
    import uvms_env

    def factory(k: int):
        return uvms_env.parallel_env(scenario=scenario, seed=seed + k, **overrides)

    return ParallelVecEnv(factory, n_envs, seed=seed)


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
) -> Path:
    """Train and save; returns the run folder."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    if algo not in ALGO_DEFAULTS:
        raise ValueError(f"unknown algorithm {algo!r}; expected ppo or sac")
    overrides = overrides or {}
    out.mkdir(parents=True, exist_ok=True)
    venv = make_vec_env(scenario, n_envs, seed, overrides)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    if resume is not None:
        venv = VecNormalize.load(str(resume / "vecnormalize.pkl"), venv)
        model = cls.load(resume / "model.zip", env=venv, device="cpu")
        reset = False
    else:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=True, clip_obs=10.0)
        model = cls(
            "MlpPolicy",
            venv,
            seed=seed,
            device="cpu",
            policy_kwargs={"net_arch": NET},
            verbose=0,
            **ALGO_DEFAULTS[algo],
        )
        reset = True
    model.set_logger(configure(str(out), ["csv", "tensorboard"]))
    config = {
        "algo": algo,
        "scenario": scenario,
        "total_timesteps": total_timesteps,
        "n_envs": n_envs,
        "seed": seed,
        "overrides": overrides,
        "hyperparameters": ALGO_DEFAULTS[algo],
        "net_arch": NET,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2))
    callbacks = [
        CheckpointCallback(
            save_freq=max(1, 50_000 // venv.num_envs),
            save_path=str(out / "checkpoints"),
            save_vecnormalize=True,
        )
    ]
    if eval_every > 0:
        callbacks.append(_EvalCallback(algo, out, scenario, eval_every, eval_episodes, seed))
    start = time.perf_counter()
    model.learn(
        total_timesteps=total_timesteps,
        callback=CallbackList(callbacks),
        reset_num_timesteps=reset,
        progress_bar=progress,
    )
    save(model, out)
    wall = time.perf_counter() - start
    config["wall_time_s"] = wall
    config["timesteps_done"] = int(model.num_timesteps)
    (out / "config.json").write_text(json.dumps(config, indent=2))
    venv.close()
    return out


def save(model, out: Path) -> None:
    model.save(out / "model.zip")
    model.get_vec_normalize_env().save(str(out / "vecnormalize.pkl"))


def _EvalCallback(algo: str, out: Path, scenario: str, every: int, episodes: int, seed: int):
    """Every ``every`` timesteps: save, then evaluate the saved policy with the shared
    evaluation code on fixed seeds; appends to ``evaluations.csv``."""
    from stable_baselines3.common.callbacks import BaseCallback

    from baselines.evaluate import aggregate, evaluate

    class EvalCallback(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self._next = every

        def _on_step(self) -> bool:
            if self.num_timesteps < self._next:
                return True
            self._next += every
            snap = out / "eval_snapshot"
            snap.mkdir(exist_ok=True)
            save(self.model, snap)
            rows = evaluate([f"{algo}:{snap}"], [scenario], episodes, seed, 1, progress=False)
            s = aggregate(rows, seed)[0]
            line = f"{self.num_timesteps},{s['success_rate']},{s.get('return', np.nan)}\n"
            path = out / "evaluations.csv"
            if not path.exists():
                path.write_text("timesteps,success_rate,mean_return\n")
            with open(path, "a") as fh:
                fh.write(line)
            self.logger.record("eval/success_rate", s["success_rate"])
            self.logger.record("eval/mean_return", s.get("return", np.nan))
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
    ap.add_argument("--resume", type=Path, default=None, help="run folder to continue")
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
    )
    print(f"saved {out / 'model.zip'} and {out / 'vecnormalize.pkl'}")


if __name__ == "__main__":
    main()
