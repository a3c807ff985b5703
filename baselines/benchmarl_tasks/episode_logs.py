"""The episodes' metrics in BenchMARL's logs: ``ended_episodes`` reads them from a batch or
a rollout (the infos of each episode's last step, ``CoopTransportTorchRLEnv(info=True)``),
and the callback ``EpisodeMetrics`` adds an evaluation's episodes to BenchMARL's evaluation
scalars and marl-eval JSON.

BenchMARL 1.5.2 logs a task's infos in collection only (``Task.log_info`` and its mean of
``(group, info)`` over every collected frame); its evaluation logs and JSON hold the return
alone and have no task hook. Its mechanism for more is a ``Callback``, which Experiment
takes as an argument and ``benchmarl.run``/``benchmarl.evaluate`` never pass: the
package's ``run_experiment`` and ``evaluate_checkpoint`` are those commands with it.

In the JSON the metrics are named as ``baselines.evaluation.marl_eval`` names them, one
value per episode (0/1 for success and clean success), so that the two tools' files merge.

May import: torch, tensordict, benchmarl, ``uvms_env.env.infos`` and
``uvms_env.vector.torchrl_env`` (names).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import torch
from benchmarl.experiment import Callback
from tensordict import TensorDictBase

from uvms_env.env.infos import CONSTRAINT_PREFIX
from uvms_env.vector.torchrl_env import GROUP

# per-step infos, and how an episode ended (a code, no quantity to average); every other
# key is an ended episode's value
NOT_LOGGED = ("cost", "episode_end")


def logged(key: str) -> bool:
    return key not in NOT_LOGGED and not key.startswith(CONSTRAINT_PREFIX)


def ended_episodes(data: TensorDictBase | Iterable[TensorDictBase]) -> dict[str, torch.Tensor]:
    """Each episode that ends in ``data`` (a batch of any shape, or rollouts): its infos at
    its last step, averaged over the robots (they are the team's, except the per-robot
    ``episode_cost``), one value per episode in float64. {} when none ends."""
    parts = [data] if isinstance(data, TensorDictBase) else list(data)
    out: dict[str, list[torch.Tensor]] = {}
    for td in parts:
        done = td.get(("next", "done"))[..., 0]
        info = td.get(("next", GROUP, "info"))
        if not bool(done.any()):
            continue
        for key, value in info.items():
            if logged(key):
                out.setdefault(key, []).append(value[done].to(torch.float64).mean(-1))
    return {key: torch.cat(values) for key, values in out.items()}


class EpisodeMetrics(Callback):
    """Adds each evaluation's episodes to BenchMARL's evaluation logs: the scalars
    ``eval/uvms/episode/<key>`` (the mean over the episodes; NaN-free keys only) and, in
    the marl-eval JSON, one list per key in the evaluation's step (BenchMARL's writer, so
    ``absolute_metrics`` holds each key's maximum as it does the return's)."""

    def on_evaluation_end(self, rollouts: list[TensorDictBase]) -> None:
        experiment = self.experiment
        # BenchMARL's log_evaluation has cut each rollout at its first done: its last step
        values = {
            key: v for key, v in ended_episodes(rollouts).items() if not bool(v.isnan().all())
        }
        if not values:
            return
        experiment.logger.log(
            {f"eval/{GROUP}/episode/{key}": float(v.nanmean()) for key, v in values.items()},
            step=experiment.n_iters_performed,
        )
        writer = experiment.logger.json_writer
        if writer is not None:
            writer.write(
                total_frames=experiment.total_frames,
                metrics=values,
                evaluation_step=experiment.total_frames // experiment.config.evaluation_interval,
            )

    def __getstate__(self) -> dict[str, Any]:
        # BenchMARL pickles its callbacks into config.pkl: not the experiment they serve
        return {**self.__dict__, "experiment": None}


def attach(experiment: Any) -> None:
    """Give ``experiment`` (built, e.g. by ``reload_experiment_from_file``) the callback,
    unless it has it (``Experiment.reload_from_file`` restores the pickled ones)."""
    if not any(isinstance(c, EpisodeMetrics) for c in experiment.callbacks):
        callback = EpisodeMetrics()
        callback.experiment = experiment
        # a tuple when the experiment came from Hydra (load_experiment_from_hydra's default)
        experiment.callbacks = [*experiment.callbacks, callback]
