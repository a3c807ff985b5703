"""BenchMARL tasks over the batched environment: ``uvms/paper``, ``uvms/short``,
``uvms/random_n2``, ``uvms/random_n4``, and one command to run BenchMARL's algorithms:

    python examples/benchmarl/benchmarl_task.py --algorithm mappo --task uvms/random_n2 \\
        --frames 1000000 --seed 0 --out runs/benchmarl

Each task is a ``UVMSTask`` member whose ``UVMSTaskClass`` builds BenchMARL's env as one
``CoopTransportTorchRLEnv`` over a float32 ``VectorEnv`` of BenchMARL's ``num_envs``
(the robots one group ``uvms``, the global state for centralized critics, continuous
actions only). ``--algorithm``: mappo, ippo, masac (or any of BenchMARL's
continuous-action algorithms by its config name).

BenchMARL 1.5.2 (the newest) needs ``torchrl>=0.10,<0.12`` and imports
``torchrl.collectors.SyncDataCollector``, which torchrl 0.14 no longer has, while this
project's TorchRL env is tested with torchrl 0.14.1. It is therefore an example outside
the package, run in a virtual environment of its own (this folder's README).

Imports torch, torchrl, benchmarl and ``uvms_env.vector``.
"""

from __future__ import annotations

import argparse
import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import EnvBase

ENV_NAME = "uvms"
# One default config per task: the scenario, its options and the batched env's settings
# (the SB3 trainer's: float32, 1 thread, seeded families on 1,024 bank geometries).
TASKS: dict[str, dict[str, Any]] = {
    "PAPER": {"scenario": "paper", "options": {}},
    "SHORT": {"scenario": "short", "options": {}},
    "RANDOM_N2": {"scenario": "random", "options": {"n_agents": 2}},
    "RANDOM_N4": {"scenario": "random", "options": {"n_agents": 4}},
}
ENV_DEFAULTS: dict[str, Any] = {
    "dtype": "float32",
    "threads": 1,
    "geometry_pool": 1024,
    "internal_wrench_every": 0,
}
SEEDED = ("short", "random")


class UVMSTaskClass(TaskClass):
    """A task's env factory and specs for BenchMARL (see module docstring)."""

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        if not continuous_actions:
            raise ValueError("the uvms tasks have continuous actions only")
        config = copy.deepcopy(self.config)

        def make() -> EnvBase:
            from uvms_env.vector import VectorEnv
            from uvms_env.vector.torchrl_env import CoopTransportTorchRLEnv

            options = {**ENV_DEFAULTS, **config.get("options", {})}
            if config["scenario"] not in SEEDED:
                options.pop("geometry_pool")
            venv = VectorEnv(config["scenario"], num_envs=num_envs, **options)
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
        return int(env.vector_env.max_cycles)

    def has_render(self, env: EnvBase) -> bool:
        return False

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    # BenchMARL's models take one env's specs: the batch dimension (K,) goes
    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        del spec["state"]  # the critic's, under state_spec
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
    """The uvms tasks; ``get_task()`` takes its defaults from ``TASKS``, not from a yaml
    inside BenchMARL's package."""

    PAPER = None
    SHORT = None
    RANDOM_N2 = None
    RANDOM_N4 = None

    @staticmethod
    def associated_class() -> type[TaskClass]:
        return UVMSTaskClass

    def get_task(self, config: dict[str, Any] | None = None) -> TaskClass:
        return UVMSTaskClass(self.name, copy.deepcopy(config or TASKS[self.name]))


def task(name: str, options: dict[str, Any] | None = None) -> TaskClass:
    """``uvms/random_n2`` (or ``random_n2``) with extra environment ``options``."""
    member = UVMSTask[name.removeprefix(f"{ENV_NAME}/").upper()]
    config = copy.deepcopy(TASKS[member.name])
    config["options"].update(options or {})
    return member.get_task(config)


def experiment(algorithm: str, task_name: str, frames: int, seed: int, out: Path, **overrides: Any):
    """BenchMARL's ``Experiment`` with its default yaml configs (MLP actor and critic),
    ``frames`` environment frames, saving under ``out``."""
    from benchmarl import algorithms
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    configs = {name.lower().removesuffix("config"): cls for name, cls in vars(algorithms).items()}
    if algorithm not in configs:
        raise ValueError(f"unknown BenchMARL algorithm {algorithm!r}")
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = frames
    config.save_folder = str(out)
    config.loggers = ["csv"]
    config.sampling_device = config.train_device = "cpu"
    for key, value in overrides.items():
        setattr(config, key, value)
    out.mkdir(parents=True, exist_ok=True)
    return Experiment(
        task=task(task_name),
        algorithm_config=configs[algorithm].get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=seed,
        config=config,
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python examples/benchmarl/benchmarl_task.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--algorithm", default="mappo", help="mappo, ippo, masac, ...")
    ap.add_argument("--task", default="uvms/random_n2", help="uvms/{paper,short,random_n2,n4}")
    ap.add_argument("--frames", type=int, default=1_000_000, help="environment frames")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--experiment-option",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="an ExperimentConfig field, e.g. on_policy_collected_frames_per_batch=6000",
    )
    ap.add_argument("--out", type=Path, default=Path("runs/benchmarl"))
    args = ap.parse_args(argv)
    overrides = {}
    for item in args.experiment_option:
        key, _, value = item.partition("=")
        overrides[key] = json.loads(value)
    experiment(args.algorithm, args.task, args.frames, args.seed, args.out, **overrides).run()


if __name__ == "__main__":
    main()
