"""``python -m baselines.benchmarl_tasks.run_experiment``: ``python -m benchmarl.run`` with the
callback ``episode_logs.EpisodeMetrics``, so that the evaluations log the episodes'
success, violations and costs beside the return. The same config and Hydra overrides
(``algorithm=mappo task=uvms/random_n2 seed=0 experiment.loggers=[csv] ...``, ``-m``).

May import: hydra, omegaconf, benchmarl and ``baselines.benchmarl_tasks``.
"""

from __future__ import annotations

import hydra
from benchmarl.hydra_config import load_experiment_from_hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

import baselines.benchmarl_tasks  # noqa: F401  (registers the tasks before Hydra reads them)
from baselines.benchmarl_tasks.episode_logs import EpisodeMetrics


@hydra.main(version_base=None, config_path="pkg://benchmarl.conf", config_name="config")
def main(cfg: DictConfig) -> None:
    """As ``benchmarl.run.hydra_experiment``, with ``EpisodeMetrics``."""
    choices = HydraConfig.get().runtime.choices
    print(f"\nAlgorithm: {choices.algorithm}, Task: {choices.task}")
    print("\nLoaded config:\n")
    print(OmegaConf.to_yaml(cfg))
    experiment = load_experiment_from_hydra(
        cfg, task_name=choices.task, callbacks=[EpisodeMetrics()]
    )
    experiment.run()


if __name__ == "__main__":
    main()
