"""BenchMARL tasks over the project's batched environment: ``uvms/paper``, ``uvms/short``,
``uvms/random_n2`` and ``uvms/random_n4`` (docs/benchmarl.md).

Importing the package registers them with BenchMARL (``tasks.register``). BenchMARL's
own commands (``python -m benchmarl.run``, ``python -m benchmarl.evaluate``) never import
it: the Hydra plugin ``hydra_plugins.uvms_coop_benchmarl`` (installed with the project)
does, and adds this package's ``conf`` folder to Hydra's config search path.
``run_experiment`` and ``evaluate_checkpoint`` are those commands with the callback of
``episode_logs``, which puts the episodes' metrics in the evaluations' scalars and
marl-eval JSON; ``baselines.train --library benchmarl`` trains these tasks under the
project's run folder (``baselines.rl.benchmarl_trainer``).

May import: benchmarl, hydra, torch, tensordict, torchrl and ``uvms_env``.
"""

from baselines.benchmarl_tasks.tasks import (
    CONF_DIR,
    ENV_NAME,
    UVMSTask,
    UVMSTaskClass,
    UVMSTaskConfig,
    read_config,
    register,
)

__all__ = [
    "CONF_DIR",
    "ENV_NAME",
    "UVMSTask",
    "UVMSTaskClass",
    "UVMSTaskConfig",
    "read_config",
    "register",
]

register()
