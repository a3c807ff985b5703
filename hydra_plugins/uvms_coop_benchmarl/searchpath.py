"""Makes BenchMARL's Hydra commands find the uvms tasks: ``python -m benchmarl.run
task=uvms/random_n2 ...`` and ``python -m benchmarl.evaluate CHECKPOINT``.

BenchMARL looks a task up in two places: its yaml on Hydra's config search path (BenchMARL
searches only its own package) and its enum member in ``task_config_registry``, which it
fills from a fixed list of environments. It offers no hook for another package, but
Hydra imports every module of the namespace package ``hydra_plugins`` and calls each
``SearchPathPlugin`` whenever it builds a config search path: for ``@hydra.main`` and for
``initialize``/``compose``, which ``reload_experiment_from_file`` uses. That call is the
one moment before BenchMARL reads the task, so the plugin registers the tasks there too.

May import: importlib, hydra and ``baselines.benchmarl_tasks`` (on call).
"""

from __future__ import annotations

import importlib.util

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class UVMSCoopSearchPathPlugin(SearchPathPlugin):
    """Appends ``pkg://baselines.benchmarl_tasks.conf`` (task group ``uvms``) to the path."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        # Imported on call, not at module level: Hydra's plugin scan turns an ImportError
        # into a warning and drops the plugin, so a broken install would surface only as
        # "Could not find 'task/uvms/...'"; here it fails with its own traceback. Hydra
        # calls the plugin in every program that uses Hydra: without BenchMARL no command
        # reads these tasks, and the plugin stays out of the way.
        if importlib.util.find_spec("benchmarl") is None:
            return
        from baselines.benchmarl_tasks import register

        register()  # idempotent; explicit rather than the import's one-time side effect
        search_path.append(provider="uvms-coop", path="pkg://baselines.benchmarl_tasks.conf")
