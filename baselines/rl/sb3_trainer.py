"""The stable-baselines3 trainer of ``python -m baselines.train``: PPO or SAC, one policy
shared by all robots (usage: ``baselines.train``).

Every robot of every env copy is a sub-environment of one batched ``VectorVecEnv``, so
one policy learns from all robots' local observations; observations and rewards are
normalized (``VecNormalize``, saved with the model). The run folder also gets
``model.zip``, ``vecnormalize.pkl`` (SAC: ``replay_buffer.pkl``) and ``checkpoints/``.
Flags and the modules behind them: docs/rl.md.

May import: numpy, torch and stable-baselines3 (inside the trainer), ``baselines.runs``,
``baselines.evaluation.during_training`` (the shield's records),
``baselines.lagrangian``, ``baselines.loaders.saved`` (a run's priors), ``baselines.rl``,
``baselines.command_line`` (the flags' types) and ``uvms_env``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

from baselines.command_line import non_negative_float, non_negative_int
from baselines.loaders.saved import priors_from_options
from baselines.loaders.sb3_policy import ALGOS, algorithm_class
from baselines.runs import (
    DEFAULT_DTYPE,
    DEFAULT_ENV_THREADS,
    DTYPES,
    Run,
    add_step_arguments,
    seeded_pool,
)

if TYPE_CHECKING:
    from baselines.lagrangian import CostSettings

# Seeded families: every episode a geometry of the bank's first 1,024 seeds (built once,
# kept on disk): diverse starts without building a geometry inside a step.
# 64 copies: the batched step and torch's forward amortize their per-call cost over many
# robots (benchmarks/train_throughput.py).
DEFAULTS: dict[str, Any] = {"num_envs": 64, "geometry_pool": 1024}
SEVERAL_TEAM_SIZES = True  # one group of env copies per team size (``make_vec_env``)
ALGO_DEFAULTS: dict[str, dict[str, Any]] = {
    # PPO, chosen for learning (docs/rl.md, "Why the defaults"): rollouts of 128 steps per
    # sub-env (4x the throughput setting's 32, still many copies), 5 epochs of 4
    # minibatches, gamma 0.995 (a ~200-period horizon on 700-3,000-period episodes: a
    # success 500 periods ahead counts 8 %, under 0.99 0.7 %). The throughput setting
    # (32 steps, 4 epochs, gamma 0.99: benchmarks/train_throughput.py) learned no better
    # and ran no faster on the distribution in the from-scratch audit
    # (docs/notes/2026-12-02-from-scratch-audit.md).
    # SAC: SB3 defaults except a short warm-up, a replay buffer sized to
    # our budgets and one gradient step per collected robot-step (gradient_steps = the
    # number of sub-environments, set in ``build``).
    "ppo": {
        "n_steps": 128,
        "n_epochs": 5,
        "batch_size": 256,
        "gae_lambda": 0.95,
        "gamma": 0.995,
        "ent_coef": 0.0,
    },
    "sac": {
        "learning_starts": 2000,
        "batch_size": 256,
        "gamma": 0.99,
        "train_freq": 1,
        "buffer_size": 50_000,
    },
}
# sb3-contrib's RecurrentPPO (an LSTM before the actor's and the critic's MLPs): PPO's
# settings; its minibatches are whole sequences of a sub-environment's rollout
ALGO_DEFAULTS["recurrent_ppo"] = dict(ALGO_DEFAULTS["ppo"])
# PPO, batch_size not given: n_steps * sub-envs / 4 (4 minibatches per epoch), at least
# 256. Small minibatches made the update dominate the wall time (the measured figures:
# docs/rl.md, "The sb3 trainer").
PPO_MINIBATCHES = 4
PPO_MIN_BATCH = 256
NET = [64, 64]
# PPO starts with action std exp(-1) ~ 0.37 instead of 1: with std 1 nearly every step
# violates the joint and vehicle speed limits and the penalties swamp the progress term.
# RecurrentPPO: a 64-unit LSTM (sb3-contrib's default 256 would dominate the update time
# of a 64-64 network) shared by nothing: the critic has its own.
POLICY_KWARGS: dict[str, dict[str, Any]] = {
    "ppo": {"log_std_init": -1.0},
    "sac": {},
    "recurrent_ppo": {"log_std_init": -1.0, "lstm_hidden_size": 64},
}
ON_POLICY = ("ppo", "recurrent_ppo")
DEFAULT_GEOMETRY_POOL = DEFAULTS["geometry_pool"]


OPTIONS_NOTE = "--hp KEY=JSON: an argument of SB3's PPO or SAC (policy_kwargs adds to the defaults)"


def add_arguments(g: Any) -> None:
    """The SB3 trainer's own options."""
    add_step_arguments(g)
    g.add_argument(
        "--central-critic",
        action="store_true",
        help="MAPPO: the critic also reads the global state (PPO)",
    )
    g.add_argument(
        "--filter",
        action="store_true",
        help="shielded training: every robot's command passes the expert's safety filter "
        "before the env (baselines.rl.shield)",
    )
    g.add_argument(
        "--filter-penalty",
        type=non_negative_float,
        default=None,
        metavar="W",
        help="with --filter: each robot's reward minus W |a_safe - a_prop|^2 (command space; "
        f"default {FILTER_PENALTY})",
    )
    g.add_argument(
        "--init-actor",
        default=None,
        metavar="SOURCE",
        help="PPO's actor starts as a clone: dagger:pretrained, dagger:PATH or bc:PATH "
        "(needs action_mode=residual and the clone's inputs as observation_mode: features "
        "or memory; baselines.rl.init_actor)",
    )
    g.add_argument(
        "--anchor",
        type=non_negative_float,
        default=0.0,
        metavar="W",
        help="with --init-actor: each robot's reward minus W times the squared distance "
        "of its residual from the clone's (baselines.rl.anchor)",
    )
    g.add_argument(
        "--critic-warmup",
        type=non_negative_int,
        default=0,
        metavar="ROBOT_STEPS",
        help="PPO: the actor stays fixed for this many robot-steps while the critic learns",
    )
    g.add_argument(
        "--obs-stats",
        choices=OBS_STATS,
        default="moving",
        help="with --init-actor: the observation statistics (VecNormalize's, the clone's at "
        "the start) move with training (moving), are frozen with the actor during "
        "--critic-warmup (warmup), or never move (frozen)",
    )


# --obs-stats: when VecNormalize's observation statistics move (baselines.rl.init_actor)
OBS_STATS = ("moving", "warmup", "frozen")

# what SB3's algorithms take that is no hyperparameter of ``--hp`` (the trainer sets them)
NOT_HYPERPARAMETERS = ("self", "policy", "env", "seed", "device", "verbose", "_init_setup_model")


# shielded training's penalty weight where --filter comes without --filter-penalty
FILTER_PENALTY = 1.0


def filter_penalty(args: argparse.Namespace) -> float | None:
    """The shield's penalty weight of a run (None: no shield)."""
    if not getattr(args, "filter", False):
        return None
    value = getattr(args, "filter_penalty", None)
    return FILTER_PENALTY if value is None else value


def check_options(settings: Any, algo: str, args: argparse.Namespace) -> None:
    """ValueError naming the option where this trainer cannot honour ``settings``
    (``baselines.runs.RunSettings``) or its own options ``args``: before any work."""
    import inspect

    if algo not in ALGO_DEFAULTS:
        raise ValueError(f"unknown algorithm {algo!r}; expected one of {ALGOS}")
    if args.central_critic and algo != "ppo":
        raise ValueError("--central-critic (MAPPO) needs --algo ppo (no LSTM)")
    if getattr(args, "init_actor", None) and algo != "ppo":
        raise ValueError("--init-actor initializes PPO's actor (--algo ppo)")
    if getattr(args, "anchor", 0.0) and not getattr(args, "init_actor", None):
        raise ValueError("--anchor keeps PPO near its initial clone: give --init-actor")
    if getattr(args, "critic_warmup", 0) and algo not in ON_POLICY:
        raise ValueError(f"--critic-warmup holds PPO's actor: --algo {' or '.join(ON_POLICY)}")
    obs_stats = getattr(args, "obs_stats", "moving")
    if obs_stats != "moving" and not getattr(args, "init_actor", None):
        raise ValueError(f"--obs-stats {obs_stats} keeps the clone's statistics: give --init-actor")
    if obs_stats == "warmup" and not getattr(args, "critic_warmup", 0):
        raise ValueError("--obs-stats warmup freezes them during --critic-warmup: give it")
    if getattr(args, "filter_penalty", None) is not None and not getattr(args, "filter", False):
        raise ValueError("--filter-penalty weighs the safety filter's corrections: give --filter")
    if getattr(args, "filter", False) and len(settings.groups()) > 1:
        raise ValueError(
            "shielded training (--filter) takes one team size and object (--n-agents N)"
        )
    taken = inspect.signature(algorithm_class(algo).__init__).parameters
    known = sorted(k for k in taken if k not in NOT_HYPERPARAMETERS)
    unknown = sorted(set(settings.hyperparameters) - set(known))
    if unknown:
        raise ValueError(f"--hp {unknown}: SB3's {algo} takes none of them; it takes {known}")


def env_settings(
    scenario: str,
    dtype: str = DEFAULT_DTYPE,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    env_threads: int | None = DEFAULT_ENV_THREADS,
    overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The environment settings a run uses (recorded in config.json): the batched step's
    ``dtype``, ``geometry_pool`` (seeded families only, else None) and ``env_threads``."""
    if dtype not in DTYPES:
        raise ValueError(f"unknown dtype {dtype!r}; expected one of {DTYPES}")
    return {
        "dtype": dtype,
        "geometry_pool": seeded_pool(scenario, overrides or {}, geometry_pool),
        "env_threads": env_threads,
    }


def make_vec_env(
    scenario: str,
    num_envs: int,
    seed: int,
    groups: list[dict[str, Any]],
    dtype: str = DEFAULT_DTYPE,
    geometry_pool: int | None = DEFAULT_GEOMETRY_POOL,
    env_threads: int | None = DEFAULT_ENV_THREADS,
    cost: CostSettings | None = None,
    central_critic: bool = False,
    filter_penalty: float | None = None,
):
    """``CostPenalty`` (with ``cost``) over ``ShieldPenalty`` (with ``filter_penalty``) over
    ``VecMonitor`` over one ``VectorEnv`` of ``num_envs`` env copies per group (each of
    ``groups`` its environment options: ``RunSettings.groups``), as ``num_envs * N``
    robot sub-environments each (in ``dtype``, on ``env_threads`` threads, None: all cores;
    seeded families: episodes on the first ``geometry_pool`` bank geometries, 0 or None:
    each copy keeps its first). Several groups sit side by side (``ConcatVecEnv``), the
    central critic's state padded to the largest team. ``filter_penalty``: shielded
    training, ``baselines.rl.shield.ShieldPenalty`` with that weight (one group)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import PART_SEED_STRIDE, ConcatVecEnv, VectorVecEnv

    settings = env_settings(scenario, dtype, geometry_pool, env_threads, groups[0])
    if filter_penalty is not None and len(groups) > 1:
        raise ValueError("shielded training (--filter) takes one group of env copies")
    parts, inners = [], []
    for j, group in enumerate(groups):
        kwargs = dict(group)
        if settings["geometry_pool"] is not None:
            kwargs["geometry_pool"] = settings["geometry_pool"]
        inner = VectorEnv(
            scenario,
            num_envs=num_envs,
            dtype=settings["dtype"],
            threads=settings["env_threads"],
            **kwargs,
        )
        part: Any = VectorVecEnv(inner, seed=seed + j * PART_SEED_STRIDE)
        if central_critic:
            from baselines.rl.mappo import CentralStateVecEnv

            most = max(g.get("n_agents", inner.n) for g in groups) if len(groups) > 1 else None
            part = CentralStateVecEnv(part, max_agents=most)
        parts.append(part)
        inners.append(inner)
    venv: Any = parts[0] if len(parts) == 1 else ConcatVecEnv(parts)
    # VecMonitor below the filter's and the cost's penalties: episodes' returns are the
    # environment's team reward (neither normalized nor penalized), as every trainer records
    venv = VecMonitor(venv)
    if filter_penalty is not None:
        from baselines.rl.shield import Shield, ShieldPenalty

        venv = ShieldPenalty(venv, Shield(inners[0], filter_penalty))
    if cost is not None:
        from baselines.rl.cost import CostPenalty

        venv = CostPenalty(venv, cost)
    return venv


def find_resume(path: Path) -> tuple[Path, Path, Path | None]:
    """(model.zip, vecnormalize.pkl, replay buffer or None) to resume from ``path``: a run
    folder (its ``model.zip``, or its newest checkpoint when it has none or the
    checkpoint is newer) or a checkpoint ``.zip``."""
    from baselines.rl.sb3_callbacks import CHECKPOINTS

    path = Path(path)
    if path.is_file():
        model = path
    else:
        candidates = sorted(
            (path / CHECKPOINTS).glob("rl_model_*_steps.zip"), key=_checkpoint_steps
        )
        model = candidates[-1] if candidates else path / "model.zip"
        final = path / "model.zip"
        if final.exists() and (not candidates or final.stat().st_mtime >= model.stat().st_mtime):
            model = final
    if not model.exists():
        raise FileNotFoundError(f"nothing to resume at {path}")
    if model.parent.name == CHECKPOINTS:
        steps = _checkpoint_steps(model)
        norm = model.parent / f"rl_model_vecnormalize_{steps}_steps.pkl"
        buffer = model.parent / f"rl_model_replay_buffer_{steps}_steps.pkl"
    else:
        norm = model.parent / "vecnormalize.pkl"
        buffer = model.parent / "replay_buffer.pkl"
    if not norm.exists():
        raise FileNotFoundError(f"no VecNormalize statistics {norm} next to {model}")
    return model, norm, buffer if buffer.exists() else None


def checkpoint_multiplier(model: Path) -> float | None:
    """The cost's multiplier saved with the checkpoint ``model``
    (``checkpoints/rl_model_<steps>_steps.zip``, ``RunCheckpoints``); None for another file
    or a checkpoint saved without one (no cost, or a run older than these files)."""
    from baselines.rl.sb3_callbacks import CHECKPOINTS, MULTIPLIER_CHECKPOINT, MULTIPLIER_KEY

    if model.parent.name != CHECKPOINTS:
        return None
    steps = _checkpoint_steps(model)
    saved = model.parent / f"rl_model_{MULTIPLIER_CHECKPOINT}{steps}_steps.json"
    if not saved.is_file():
        return None
    return float(json.loads(saved.read_text())[MULTIPLIER_KEY])


def _checkpoint_steps(path: Path) -> int:
    return int(path.stem.split("_")[-2])


class Trainer:
    """SB3's PPO or SAC under a ``baselines.runs.Run`` (``baselines.runs.Trainer``)."""

    def __init__(self, run: Run, algo: str, args: argparse.Namespace) -> None:
        check_options(run.settings, algo, args)
        self.run, self.algo, self.args = run, algo, args
        self.model: Any = None
        self.venv: Any = None
        self.penalty: Any = None
        self.shield: Any = None
        self.resumed_from: Path | None = None

    def build(self) -> dict[str, Any]:
        import torch
        from stable_baselines3.common.logger import configure

        from baselines.rl.cost import CostPenalty, find_layer

        torch.set_num_threads(1)
        s, a, algo = self.run.settings, self.args, self.algo
        hyperparameters = dict(s.hyperparameters)
        hp = {**ALGO_DEFAULTS[algo], **hyperparameters}
        chosen_policy_kwargs, clone = self._policy_kwargs(hp)
        settings = env_settings(s.scenario, a.dtype, s.geometry_pool, a.env_threads, s.overrides)
        venv = make_vec_env(
            s.scenario,
            s.num_envs,
            self.run.env_seed,
            s.groups(),
            **settings,
            cost=s.cost,
            central_critic=a.central_critic,
            filter_penalty=filter_penalty(a),
        )
        venv = self._anchored(venv, clone)
        if s.resume is not None:
            model, venv = self._resumed(venv, hp)
        else:
            if algo in ON_POLICY and "batch_size" not in hyperparameters:
                rollout = hp["n_steps"] * venv.num_envs
                hp["batch_size"] = max(PPO_MIN_BATCH, rollout // PPO_MINIBATCHES)
            model, venv = self._new_model(venv, hp, chosen_policy_kwargs, clone)
        if algo in ON_POLICY:
            hp["batch_size"] = model.batch_size  # the one used (a resumed model keeps its own)
        # SB3's own scalars go to tensorboard; the shared progress.csv is the run's
        model.set_logger(configure(str(self.run.folder), ["tensorboard"]))
        self.model, self.venv = model, venv
        self._hold(model, venv)
        self.penalty = find_layer(venv, CostPenalty)
        if s.resume is not None and self.penalty is not None:
            self._resume_multiplier()
        from baselines.rl.shield import ShieldPenalty

        shielded = find_layer(venv, ShieldPenalty)
        self.shield = shielded.shield if shielded is not None else None
        return {
            **settings,
            "robot_sub_envs": venv.num_envs,
            "hyperparameters": hp,
            "net_arch": NET,
            "policy_kwargs": chosen_policy_kwargs,
            "central_critic": a.central_critic,
            "torch_threads": torch.get_num_threads(),
            "filter": {"penalty": filter_penalty(a)} if self.shield is not None else None,
            "init_actor": getattr(a, "init_actor", None),
            "critic_warmup": getattr(a, "critic_warmup", 0),
            "obs_stats": getattr(a, "obs_stats", "moving"),
            "anchor": getattr(a, "anchor", 0.0),
        }

    def _hold(self, model: Any, venv: Any) -> None:
        """What stays fixed from the start (before SB3's first reset, which would move the
        statistics): the actor during ``--critic-warmup``, the observation statistics as
        ``--obs-stats`` says; the progress callback releases both when the warm-up ends."""
        from baselines.rl.init_actor import freeze_actor, freeze_statistics

        warming = model.num_timesteps < getattr(self.args, "critic_warmup", 0)
        if warming:
            freeze_actor(model.policy, True)
        obs_stats = getattr(self.args, "obs_stats", "moving")
        if obs_stats != "moving":
            freeze_statistics(venv, obs_stats == "frozen" or warming)

    def _policy_kwargs(self, hp: dict[str, Any]) -> tuple[dict[str, Any], Any]:
        """The policy's keyword arguments (taken out of ``hp``) and, with ``--init-actor``
        on a new run, the clone the actor starts as (else None)."""
        s, a = self.run.settings, self.args
        # ``--hp policy_kwargs={...}`` adds to the defaults (e.g. log_std_init) instead of
        # replacing them; a resumed model keeps its own.
        policy_extra = hp.pop("policy_kwargs", None) or {}
        if not isinstance(policy_extra, dict):
            raise ValueError(f"policy_kwargs must be a JSON object, got {policy_extra!r}")
        chosen = {**POLICY_KWARGS[self.algo], **policy_extra}
        if not getattr(a, "init_actor", None) or s.resume is not None:
            return chosen, None
        from baselines.rl import init_actor

        clone = init_actor.load_clone(a.init_actor)
        init_actor.check_priors(priors_from_options(s.env_options()), clone)
        if "log_std_init" not in policy_extra:
            chosen.pop("log_std_init", None)
        return init_actor.policy_kwargs(clone, chosen), clone

    def _anchored(self, venv: Any, clone: Any) -> Any:
        """``venv`` with ``--anchor``'s penalty (the reward keeps PPO near its clone)."""
        s, a = self.run.settings, self.args
        anchor = getattr(a, "anchor", 0.0)
        if not anchor:
            return venv
        from baselines.rl import init_actor
        from baselines.rl.anchor import AnchorPenalty

        scale = priors_from_options(s.env_options()).residual_scale
        reference = clone if clone is not None else init_actor.load_clone(a.init_actor)
        return AnchorPenalty(venv, reference, scale, anchor)

    def _resumed(self, venv: Any, hp: dict[str, Any]) -> tuple[Any, Any]:
        """The model and normalized env of ``--resume`` (SAC: its replay buffer and its
        gradient steps, recorded into ``hp``)."""
        from stable_baselines3.common.vec_env import VecNormalize

        model_path, norm_path, buffer_path = find_resume(Path(self.run.settings.resume))
        self.resumed_from = model_path
        venv = VecNormalize.load(str(norm_path), venv)
        venv.training = True
        model = algorithm_class(self.algo).load(model_path, env=venv, device="cpu")
        if buffer_path is not None and hasattr(model, "load_replay_buffer"):
            model.load_replay_buffer(buffer_path)
        if self.algo == "sac":
            hp["gradient_steps"] = model.gradient_steps
        print(f"resuming {model_path} at {model.num_timesteps} robot-steps")
        return model, venv

    def _resume_multiplier(self) -> None:
        """A resume from a checkpoint starts from the multiplier saved with it (config.json
        records it as the session's start); from the run's final model, from the previous
        session's last (``Run.start``)."""
        from baselines.rl.sb3_callbacks import CHECKPOINTS

        if self.resumed_from is None:
            return
        saved = checkpoint_multiplier(self.resumed_from)
        if saved is not None:
            self.penalty.multiplier = saved
            self.run.config["cost"]["multiplier"] = saved
        elif self.resumed_from.parent.name == CHECKPOINTS:
            print(
                f"no multiplier saved with {self.resumed_from}: the multiplier starts at "
                f"{self.penalty.multiplier:g} (the previous session's last or --cost's start)"
            )

    def _new_model(
        self, venv: Any, hp: dict[str, Any], policy_kwargs: dict[str, Any], clone: Any
    ) -> tuple[Any, Any]:
        """A new model on the normalized env (MAPPO's policy with ``--central-critic``, the
        actor from ``clone`` with ``--init-actor``)."""
        from stable_baselines3.common.vec_env import VecNormalize

        s = self.run.settings
        venv = VecNormalize(venv, clip_obs=10.0)
        if self.algo == "sac":
            hp.setdefault("gradient_steps", venv.num_envs)
        policy: Any = "MlpLstmPolicy" if self.algo == "recurrent_ppo" else "MlpPolicy"
        kwargs = {"net_arch": NET, **policy_kwargs}
        if self.args.central_critic:
            from baselines.rl.cost import find_layer
            from baselines.rl.mappo import CentralCriticPolicy, CentralStateVecEnv

            policy = CentralCriticPolicy
            kwargs["local_dim"] = find_layer(venv, CentralStateVecEnv).local_dim
        cls = algorithm_class(self.algo)
        model = cls(policy, venv, seed=s.seed, device="cpu", policy_kwargs=kwargs, verbose=0, **hp)
        if clone is not None:
            from baselines.rl import init_actor

            scale = priors_from_options(s.env_options()).residual_scale
            init_actor.initialize(model, venv, clone, scale)
        return model, venv

    def learn(self) -> int:
        from baselines.rl.sb3_callbacks import run_callbacks

        s = self.run.settings
        remaining = max(0, s.robot_steps - self.model.num_timesteps)
        callbacks = run_callbacks(
            self.run,
            self.algo in ON_POLICY,
            self.model.n_envs,
            self.args,
            self.penalty,
            self.shield,
            replay_buffer=self.algo == "sac",
        )
        self.model.learn(
            total_timesteps=remaining,
            callback=callbacks,
            reset_num_timesteps=s.resume is None,
            progress_bar=False,
        )
        return int(self.model.num_timesteps)

    def save(self, folder: Path) -> None:
        from baselines.rl.sb3_callbacks import save_model

        save_model(
            self.model, folder, replay_buffer=self.algo == "sac" and folder == self.run.folder
        )

    def results(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        if self.venv is not None:
            self.venv.close()
            self.venv = None
