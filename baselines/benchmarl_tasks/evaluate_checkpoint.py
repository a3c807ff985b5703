"""``python -m baselines.benchmarl_tasks.evaluate_checkpoint CHECKPOINT``: ``python -m
benchmarl.evaluate`` with the callback ``episode_logs.EpisodeMetrics``: one evaluation of
the checkpoint (the experiment's ``evaluation_episodes`` episodes, from its seed: the same
episodes as every evaluation of the run) into the experiment folder's scalars and marl-eval
JSON.

May import: argparse, benchmarl and ``baselines.benchmarl_tasks``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarl.hydra_config import reload_experiment_from_file

import baselines.benchmarl_tasks  # noqa: F401  (registers the tasks)
from baselines.benchmarl_tasks.episode_logs import attach


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("checkpoint_file", type=Path, help="a checkpoint_<frames>.pt")
    args = parser.parse_args(argv)
    experiment = reload_experiment_from_file(str(args.checkpoint_file.resolve()))
    attach(experiment)
    experiment.evaluate()


if __name__ == "__main__":
    main()
