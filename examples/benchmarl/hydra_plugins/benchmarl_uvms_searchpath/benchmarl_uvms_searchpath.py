"""Makes BenchMARL's Hydra commands find the uvms tasks: ``python -m benchmarl.run
task=uvms/random_n2 ...`` and ``python -m benchmarl.evaluate CHECKPOINT``.

BenchMARL looks a task up in two places: its yaml on Hydra's config search path (BenchMARL
searches only its own package) and its enum member in ``task_config_registry``, which it
fills from a fixed list of environments. It offers no hook for a third-party package, but
Hydra imports every module of the namespace package ``hydra_plugins`` and calls each
``SearchPathPlugin`` whenever it builds a config search path: for ``@hydra.main`` and for
``initialize``/``compose``, which ``reload_experiment_from_file`` uses. That call is the
one moment before BenchMARL reads the task, so the plugin registers the tasks there too.
"""

from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class BenchmarlUVMSSearchPathPlugin(SearchPathPlugin):
    """Appends ``pkg://benchmarl_uvms.conf`` (task group ``uvms``) to the search path."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        # Imported on call, not at module level: Hydra's plugin scan turns an ImportError
        # into a warning and drops the plugin, so a broken install would surface only as
        # "Could not find 'task/uvms/...'"; here it fails with its own traceback.
        from benchmarl_uvms import register

        register()  # idempotent; explicit rather than the import's one-time side effect
        search_path.append(provider="benchmarl-uvms", path="pkg://benchmarl_uvms.conf")
