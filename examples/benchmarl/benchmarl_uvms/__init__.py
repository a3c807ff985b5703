"""BenchMARL tasks over the project's batched environment: ``uvms/paper``, ``uvms/short``,
``uvms/random_n2`` and ``uvms/random_n4`` (README.md beside this package).

Importing the package registers them with BenchMARL (``tasks.register``). BenchMARL's
own commands (``python -m benchmarl.run``, ``python -m benchmarl.evaluate``) never import
it: the Hydra plugin ``hydra_plugins.benchmarl_uvms_searchpath`` does, and adds this
package's ``conf`` folder to Hydra's config search path. ``benchmarl_uvms.run`` and
``benchmarl_uvms.evaluate`` are those commands with the callback of ``metrics``, which
puts the episodes' metrics in the evaluations' scalars and marl-eval JSON.

May import: benchmarl, hydra, torch, tensordict, torchrl and ``uvms_env``.
"""

from benchmarl_uvms.tasks import (
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
