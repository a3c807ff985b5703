"""The uvms tasks as BenchMARL tasks: the enum ``UVMSTask`` (``PAPER``, ``SHORT``,
``RANDOM_N2`` ... ``RANDOM_N6``), the ``UVMSTaskClass`` that builds their TorchRL env, the
schema ``UVMSTaskConfig`` of their yaml files (``conf/task/uvms/*.yaml``), and
``register()``, which adds them to BenchMARL's ``task_config_registry`` and the schema to
Hydra's ConfigStore.

A task's env is one ``CoopTransportTorchRLEnv`` over a ``VectorEnv`` of BenchMARL's
``num_envs`` copies: the robots one group ``uvms``, the global state for centralized
critics, continuous actions only, the infos under ``(uvms, info)`` (BenchMARL's info spec:
never a model's input, left out of its training batches). Its yaml holds the ``VectorEnv``
keywords (the scenario family, team size, truncation, precision, threads, geometry pool,
backend), ``options``, any further keyword of ``uvms_env.env.parallel_env``, and
``render_every``. With ``backend: cuda`` the copies step on the GPU of BenchMARL's
``sampling_device`` (the host emulation of the kernels where that device is the CPU).

What BenchMARL gets beyond the return: ``log_info`` gives its collection scalars the
episodes that ended in the batch (``collection/uvms/episode/<key>``, the mean over them,
from their last step's infos); the evaluation's episodes go to its scalars and marl-eval
JSON through the callback ``episode_logs.EpisodeMetrics``. Every reset that
starts the copies afresh (each evaluation's rollout) starts from the experiment's seed,
so every evaluation, in training or of a checkpoint, plays the same episodes.

May import: yaml, torch, tensordict, torchrl, benchmarl, hydra,
``baselines.benchmarl_tasks.episode_logs`` and ``uvms_env.vector``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
import yaml
from benchmarl.environments import task_config_registry
from benchmarl.environments.common import Task, TaskClass
from hydra.core.config_store import ConfigStore
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase

from baselines.benchmarl_tasks.episode_logs import ended_episodes
from uvms_env.vector import VectorEnv
from uvms_env.vector.torchrl_env import GROUP, CoopTransportTorchRLEnv

ENV_NAME = "uvms"
# Where the tasks' yaml files are: the folder Hydra searches (the plugin in
# hydra_plugins/uvms_coop_benchmarl) and get_from_yaml reads.
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
    render_every: int = 0  # evaluation videos: a new picture every this many steps; 0: none
    backend: str = "cpu"  # the VectorEnv backend: cpu, or cuda on the sampling device

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
            if name not in ("scenario", "options", "render_every", "backend")
            and getattr(self, name) is not None
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

        if config.backend == "cuda":
            where = torch.device(device)
            # a GPU's index; on the CPU, the emulated CUDA device of the host
            keywords |= {"backend": "cuda", "device": where.index or 0}
            if where.type != "cuda":
                keywords["device"] = "cpu"
        elif config.backend != "cpu":
            raise ValueError(f"backend must be cpu or cuda, got {config.backend!r}")

        def make() -> EnvBase:
            venv = VectorEnv(config.scenario, num_envs=num_envs, **keywords)
            # fixed_seed: BenchMARL seeds each env once, at its creation, and its evaluations
            # start with a fresh reset, which would otherwise continue the copies' episode
            # sequences: the n-th evaluation of a run would play other episodes than the
            # first, and than a checkpoint's evaluation (a new env). The collector's env
            # resets afresh only once; after that its resets name the copies (_reset).
            env = CoopTransportTorchRLEnv(venv, device=device, info=True, fixed_seed=True)
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
        return self.config.get("render_every", 0) > 0

    @staticmethod
    def render_callback(experiment: Any, env: EnvBase, data: TensorDictBase) -> Any:
        """Copy 0's picture (``CoopTransportTorchRLEnv.render``), a new one every
        ``render_every`` steps: BenchMARL keeps one frame per step of the video's episode."""
        every = int(experiment.task.config.get("render_every", 1))
        return base_env(env).render(0, every=max(every, 1))

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    # BenchMARL's models take one copy's specs: the unbatched ones, without (K,)
    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        del spec["state"]  # the critic's input, under state_spec
        del spec[GROUP, "info"]  # never a model's input
        return spec

    def info_spec(self, env: EnvBase) -> Composite | None:
        spec = env.full_observation_spec_unbatched.clone()
        del spec["state"]
        del spec[GROUP, "observation"]
        return spec

    @staticmethod
    def log_info(batch: TensorDictBase) -> dict[str, float]:
        """The collection scalars of the episodes that ended in ``batch``: each info value
        at their last step, the mean over them (and over robots: ``episode_cost`` is per
        robot); ``collection/uvms/episode/count`` of them. Nothing when none ended (BenchMARL
        then warns that its episode returns are NaN)."""
        values = ended_episodes(batch)
        if not values:
            return {}
        out = {f"collection/{GROUP}/episode/{key}": mean(v) for key, v in values.items()}
        out[f"collection/{GROUP}/episode/count"] = float(len(next(iter(values.values()))))
        return out

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.full_observation_spec_unbatched["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


def base_env(env: EnvBase) -> CoopTransportTorchRLEnv:
    """The ``CoopTransportTorchRLEnv`` under BenchMARL's transformed envs."""
    while not isinstance(env, CoopTransportTorchRLEnv):
        env = env.base_env
    return env


def mean(values: torch.Tensor) -> float:
    """The mean of the values that are not NaN (NaN: a metric no episode has)."""
    return float(torch.nanmean(values.to(torch.float64)))


class UVMSTask(Task):
    """The uvms tasks. ``get_from_yaml()`` (and ``get_task()`` without a config) reads
    ``conf/task/uvms/<name>.yaml`` of this package: BenchMARL's own ``get_from_yaml``
    only looks inside BenchMARL's package."""

    PAPER = None
    SHORT = None
    RANDOM_N2 = None
    RANDOM_N3 = None
    RANDOM_N4 = None
    RANDOM_N5 = None
    RANDOM_N6 = None

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
