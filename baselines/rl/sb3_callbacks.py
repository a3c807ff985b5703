"""The SB3 trainer's callbacks: what a ``baselines.runs.Run`` records, done from inside
SB3's ``learn`` with the model SB3 hands them (``self.model``), never the trainer.

* ``RunProgress``: the progress row of every rollout (SAC: every ``SAC_ROW_STEPS`` steps
  of every sub-env), the bar, the cost's dual step, the end of ``--critic-warmup``;
* ``RunCheckpoints``: SB3's ``CheckpointCallback`` (its files are what ``--resume`` reads
  back) with the cost's multiplier beside each checkpoint, timed apart from training;
* ``RunEvaluation``: the periodic evaluation through the project's evaluator.

May import: stable-baselines3, ``baselines.runs``, ``baselines.evaluation.during_training``
(the shield's records), ``baselines.rl`` and ``uvms_env``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback

from baselines.runs import Run
from uvms_env.env.infos import EPISODE_END_NAMES

# SAC has no rollouts: one progress row per this many steps of every sub-environment.
SAC_ROW_STEPS = 256
CHECKPOINTS = "checkpoints"
# the multiplier in force when a checkpoint was saved: SB3's naming, a JSON of one key
MULTIPLIER_CHECKPOINT = "multiplier_"
MULTIPLIER_KEY = "multiplier"


def save_model(model: BaseAlgorithm, folder: Path, replay_buffer: bool = False) -> None:
    """``model.zip`` and ``vecnormalize.pkl`` in ``folder`` (what ``ppo:FOLDER`` loads
    and a resume reads), with ``replay_buffer`` SAC's ``replay_buffer.pkl`` too."""
    folder.mkdir(parents=True, exist_ok=True)
    model.save(folder / "model.zip")
    norm = model.get_vec_normalize_env()
    assert norm is not None  # every trainer's env is normalized
    norm.save(str(folder / "vecnormalize.pkl"))
    if replay_buffer:
        model.save_replay_buffer(folder / "replay_buffer.pkl")  # type: ignore[attr-defined]


class RunProgress(BaseCallback):
    """After each PPO rollout (SAC: every ``SAC_ROW_STEPS`` steps of every sub-env): the
    dual step of the cost's multiplier (``penalty``, a ``CostPenalty`` or None) and the
    run's progress row with the team episodes that ended (one per env copy: its first
    robot's), the shield's row (``shield`` or None) in shield.csv; the bar moves each
    step. ``warmup``: the robot-steps the actor stays fixed (``--critic-warmup``), then
    released with the observation statistics where ``release_statistics``."""

    def __init__(
        self,
        run: Run,
        on_policy: bool,
        penalty: Any = None,
        shield: Any = None,
        warmup: int = 0,
        release_statistics: bool = False,
    ) -> None:
        super().__init__()
        self.run, self.on_policy, self.penalty, self.shield = run, on_policy, penalty, shield
        self.warmup = warmup if on_policy else 0
        self.release_statistics = release_statistics
        self.returns: list[float] = []
        self.lengths: list[float] = []
        self.ends: list[str] = []

    def _init_callback(self) -> None:
        # each team's first robot: one per team episode (the wrappers' attribute look-up
        # reaches down to the batched env's)
        leaders = getattr(self.training_env, "team_leaders", None)
        self.leaders = leaders if leaders is not None else [True] * self.model.n_envs
        self.last = self.model.num_timesteps

    def _on_training_start(self) -> None:
        # after SB3's first reset of the envs: the build is over, stepping starts
        n_envs = self.model.n_envs
        if self.on_policy:
            self.run.begin(self.model.n_steps * n_envs)  # type: ignore[attr-defined]
        else:  # SAC steps every sub-env once per call
            self.run.begin(n_envs, ("step of every robot sub-env", "steps of every robot sub-env"))

    def _on_step(self) -> bool:
        for i, info in enumerate(self.locals["infos"]):
            if "episode" in info and self.leaders[i]:
                self.returns.append(float(info["episode"]["r"]))
                self.lengths.append(float(info["episode"]["l"]))
                if "episode_end" in info:
                    self.ends.append(EPISODE_END_NAMES[int(info["episode_end"])])
        self.run.advance(self.model.num_timesteps)
        return True

    def _on_rollout_end(self) -> None:
        steps = self.model.num_timesteps
        if self.warmup and steps >= self.warmup:  # the update that follows moves the actor
            from baselines.rl.init_actor import freeze_actor, freeze_statistics

            freeze_actor(self.model.policy, False)
            if self.release_statistics:
                freeze_statistics(self.model.get_vec_normalize_env(), False)
            self.warmup = 0
        if not self.on_policy and steps - self.last < SAC_ROW_STEPS * self.model.n_envs:
            return
        self._row(steps)

    def _on_training_end(self) -> None:
        if self.model.num_timesteps > self.last:  # SAC's last steps since a row
            self._row(self.model.num_timesteps)

    def _row(self, steps: int) -> None:
        self.last = steps
        penalty = self.penalty
        cost = penalty.update_multiplier() if penalty is not None else None
        row = self.run.iteration(
            steps,
            returns=self.returns,
            lengths=self.lengths,
            episode_cost=cost,
            multiplier=penalty.multiplier if penalty is not None else None,
            ends=self.ends,
        )
        # SB3's logger (tensorboard) beside progress.csv, which keeps the run's columns
        for key in ("episode_return_mean", "episode_objective_mean", "episode_cost_mean"):
            if row[key] is not None:
                self.logger.record(f"progress/{key}", row[key])
        self.returns, self.lengths, self.ends = [], [], []
        if self.shield is not None:  # the correction penalty, its own record (shield.csv)
            from baselines.evaluation.during_training import append_row
            from baselines.rl.shield import SHIELD_COLUMNS, SHIELD_FILE

            append_row(self.run.folder / SHIELD_FILE, SHIELD_COLUMNS, self.shield.summary(steps))


class RunCheckpoints(CheckpointCallback):
    """SB3's checkpoints every ``--checkpoint-every`` robot-steps (in env.step calls of
    all sub-envs) under ``checkpoints/``: ``rl_model_<steps>_steps.zip``,
    ``rl_model_vecnormalize_<steps>_steps.pkl`` (SAC: the replay buffer) and, with a
    cost (``penalty``), ``rl_model_multiplier_<steps>_steps.json``: the multiplier in
    force during the rollout the checkpoint was saved in, which a resume from it starts
    from (a killed session writes no ``final_multiplier``). The files that
    ``baselines.rl.sb3_trainer``'s ``find_resume`` and ``checkpoint_multiplier`` read
    back; their saving is no training (``Run.apart``)."""

    def __init__(
        self, run: Run, every: int, n_envs: int, replay_buffer: bool, penalty: Any = None
    ) -> None:
        super().__init__(
            max(1, every // n_envs),
            str(run.folder / CHECKPOINTS),
            save_replay_buffer=replay_buffer,
            save_vecnormalize=True,
        )
        self.run, self.penalty = run, penalty

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq:
            return True
        with self.run.apart():
            going_on = super()._on_step()
            if self.penalty is not None:
                saved = Path(self._checkpoint_path(MULTIPLIER_CHECKPOINT, extension="json"))
                saved.write_text(json.dumps({MULTIPLIER_KEY: self.penalty.multiplier}))
            return going_on


class RunEvaluation(BaseCallback):
    """Every ``--eval-every`` robot-steps (at the first rollout's end at or past each
    multiple, ``Run.due``): ``self.model`` saved as the run's snapshot and evaluated by
    ``Run.evaluate_snapshot``, which keeps the best, apart from training.

    Not SB3's ``EvalCallback``: that one plays an SB3 eval env and keeps the mean reward
    alone, while the run's evaluation plays the saved policy as the evaluator loads it
    (``ppo:SNAPSHOT``, its priors and observation normalization) on seeded episodes of
    every rung through ``baselines.evaluation`` (success, clean success, violations,
    return) and ranks snapshots by clean successes first (``evaluation_score``): the same
    rows and the same best model as every other library's trainer."""

    def __init__(self, run: Run) -> None:
        super().__init__()
        self.run = run

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        steps = self.model.num_timesteps
        if not self.run.due("eval_every", steps):
            return
        with self.run.apart():
            save_model(self.model, self.run.snapshot)
            rows = self.run.evaluate_snapshot(steps)
        for key in ("success_rate", "clean_success_rate"):
            self.logger.record(f"eval/{key}", float(np.mean([r[key] for r in rows])))


def run_callbacks(
    run: Run,
    on_policy: bool,
    n_envs: int,
    args: Any,
    penalty: Any,
    shield: Any,
    replay_buffer: bool = False,
) -> CallbackList:
    """The callbacks of one ``learn`` (``on_policy``: PPO's rollouts, else SAC's steps):
    progress, checkpoints (``--checkpoint-every`` > 0; with the ``replay_buffer``) and
    evaluations (``--eval-every`` > 0). ``args``: the trainer's own options (the warm-up
    and the observation statistics of ``--init-actor``)."""
    s = run.settings
    callbacks: list[BaseCallback] = [
        RunProgress(
            run,
            on_policy,
            penalty,
            shield,
            warmup=getattr(args, "critic_warmup", 0),
            release_statistics=getattr(args, "obs_stats", "moving") == "warmup",
        )
    ]
    if s.checkpoint_every > 0:
        callbacks.append(RunCheckpoints(run, s.checkpoint_every, n_envs, replay_buffer, penalty))
    if s.eval_every > 0:
        callbacks.append(RunEvaluation(run))
    return CallbackList(callbacks)
