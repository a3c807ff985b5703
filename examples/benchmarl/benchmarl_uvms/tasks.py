"""The uvms tasks as BenchMARL tasks: the enum ``UVMSTask`` (``PAPER``, ``SHORT``,
``RANDOM_N2``, ``RANDOM_N4``), the ``UVMSTaskClass`` that builds their TorchRL env, the
schema ``UVMSTaskConfig`` of their yaml files (``conf/task/uvms/*.yaml``), and
``register()``, which adds them to BenchMARL's ``task_config_registry`` and the schema to
Hydra's ConfigStore.

A task's env is one ``CoopTransportTorchRLEnv`` over a ``VectorEnv`` of BenchMARL's
``num_envs`` copies: the robots one group ``uvms``, the global state for centralized
critics, continuous actions only. Its yaml holds the ``VectorEnv`` keywords (the
scenario family, team size, truncation, precision, threads, geometry pool) and
``options``, any further keyword of ``uvms_env.env.parallel_env``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml
from benchmarl.environments import task_config_registry
from benchmarl.environments.common import Task, TaskClass
from hydra.core.config_store import ConfigStore
from torchrl.data import Composite
from torchrl.envs import EnvBase

from uvms_env.vector import VectorEnv
from uvms_env.vector.torchrl_env import CoopTransportTorchRLEnv

ENV_NAME = "uvms"
# Where the tasks' yaml files are: the folder Hydra searches (the plugin in
# hydra_plugins/benchmarl_uvms_searchpath) and get_from_yaml reads.
CONF_DIR = Path(__file__).resolve().parent / "conf"
# The schema's name in Hydra's ConfigStore, named in each yaml's defaults list
SCHEMA = "uvms_config"


@dataclass
class UVMSTaskConfig:
    """A uvms task's config, the keys of its yaml file. The defaults are those of the
    project's SB3 trainer (float32, one thread, episodes over 1,024 bank geometries)."""

    scenario: str = "random"  # the family: paper, short or random
    n_agents: int = 2  # team size: 2..6 for random, 2 for paper and short
    max_cycles: int | None = None  # truncation; None: the scenario's max_steps
    dtype: str = "float32"  # float32 (fast) or float64
    threads: int = 1  # CPU threads stepping the copies
    geometry_pool: int | None = 1024  # seeded families only (short, random); None: off
    internal_wrench_every: int = 0  # internal-wrench metric period; 0: never (cheaper)
    options: dict[str, Any] = field(default_factory=dict)  # more parallel_env keywords

    def env_keywords(self) -> dict[str, Any]:
        """The ``VectorEnv`` keywords after ``scenario`` and ``num_envs``: the optional
        fields that are set, then ``options``."""
        own = [f.name for f in fields(self)]
        clash = sorted(set(own) & set(self.options))
        if clash:
            raise ValueError(f"options repeats the task's own keys {clash}: set those instead")
        named = {
            name: getattr(self, name)
            for name in own
            if name not in ("scenario", "options") and getattr(self, name) is not None
        }
        return {**named, **self.options}


def read_config(path: str | Path) -> dict[str, Any]:
    """A task yaml's config checked against ``UVMSTaskConfig`` (unknown keys raise), with
    the fields it leaves out at their defaults. Hydra's ``defaults`` list is not config."""
    data = yaml.safe_load(Path(path).read_text()) or {}
    data.pop("defaults", None)
    return asdict(UVMSTaskConfig(**data))


class UVMSTaskClass(TaskClass):
    """A uvms task's env factory and specs for BenchMARL (module docstring)."""

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        if not continuous_actions:
            raise ValueError("the uvms tasks have continuous actions only")
        config = UVMSTaskConfig(**copy.deepcopy(self.config))
        keywords = config.env_keywords()  # checked here, before BenchMARL builds anything

        def make() -> EnvBase:
            venv = VectorEnv(config.scenario, num_envs=num_envs, **keywords)
            env = CoopTransportTorchRLEnv(venv, device=device)
            if seed is not None:
                env.set_seed(seed)
            return env

        return make

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        # BenchMARL passes its TransformedEnv, which hands attributes on to the base env
        return int(env.vector_env.max_cycles)

    def has_render(self, env: EnvBase) -> bool:
        return False

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    # BenchMARL's models take one copy's specs: the unbatched ones, without (K,)
    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        del spec["state"]  # the critic's input, under state_spec
        return spec

    def info_spec(self, env: EnvBase) -> Composite | None:
        return None

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.full_observation_spec_unbatched["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


class UVMSTask(Task):
    """The uvms tasks. ``get_from_yaml()`` (and ``get_task()`` without a config) reads
    ``conf/task/uvms/<name>.yaml`` of this package: BenchMARL's own ``get_from_yaml``
    only looks inside BenchMARL's package."""

    PAPER = None
    SHORT = None
    RANDOM_N2 = None
    RANDOM_N4 = None

    @staticmethod
    def associated_class() -> type[TaskClass]:
        return UVMSTaskClass

    @property
    def yaml_path(self) -> Path:
        return CONF_DIR / "task" / ENV_NAME / f"{self.name.lower()}.yaml"

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        return self.get_task(read_config(self.yaml_path if path is None else path))


def register() -> None:
    """Adds ``uvms/<task>`` to BenchMARL's ``task_config_registry`` (what ``benchmarl.run``
    and ``reload_experiment_from_file`` look task names up in) and the yaml files' schema
    to Hydra's ConfigStore. Idempotent."""
    for member in UVMSTask:
        task_config_registry[f"{ENV_NAME}/{member.name.lower()}"] = member
    ConfigStore.instance().store(group="task", name=SCHEMA, node=UVMSTaskConfig)
