"""BenchMARL's uvms tasks (examples/benchmarl: the package ``benchmarl_uvms`` and its Hydra
plugin) as a BenchMARL user runs them: the registry, ``get_from_yaml``, the Hydra configs,
the env's specs, a ``benchmarl.run`` whose checkpoint ``reload_experiment_from_file``
restores, and (slow) a multirun over MAPPO and MASAC.

BenchMARL 1.5.2 needs torchrl < 0.12 and the project's test extra torchrl >= 0.14, so
these tests run in BenchMARL's own virtual environment (examples/benchmarl/README.md) and
skip in the project's. The runs are tiny: a few hundred frames of 10-step episodes.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

SKIP = "BenchMARL has its own venv (.venv-benchmarl, torchrl < 0.12): examples/benchmarl/README.md"
# the tasks' yaml files in this checkout (the editable install reads these)
YAML_DIR = Path(__file__).resolve().parents[1] / "examples/benchmarl/benchmarl_uvms/conf/task/uvms"


@pytest.fixture(autouse=True, scope="module")
def _benchmarl() -> None:
    # Skips each test rather than the module at import: a module skipped while collecting
    # leaves `pytest tests/test_benchmarl.py` with no test collected (exit status 5).
    pytest.importorskip("benchmarl", reason=SKIP)
    pytest.importorskip("benchmarl_uvms", reason=f"pip install -e examples/benchmarl; {SKIP}")


TASKS = ("paper", "short", "random_n2", "random_n4")
# A run of 2 iterations of 4 copies x 20 steps (2 episodes each), trained on 2 minibatches
TINY = [
    "task.max_cycles=10",
    "task.geometry_pool=null",  # each copy keeps its geometry: no bank builds in the test
    "experiment.max_n_frames=160",
    "experiment.on_policy_collected_frames_per_batch=80",
    "experiment.on_policy_n_envs_per_worker=4",
    "experiment.on_policy_n_minibatch_iters=2",
    "experiment.on_policy_minibatch_size=40",
    "experiment.off_policy_collected_frames_per_batch=80",
    "experiment.off_policy_n_envs_per_worker=4",
    "experiment.off_policy_n_optimizer_steps=2",
    "experiment.off_policy_train_batch_size=40",
    "experiment.off_policy_memory_size=1000",
    "experiment.evaluation=false",
    "experiment.evaluation_episodes=3",
    "experiment.loggers=[csv]",
    "experiment.checkpoint_at_end=true",
]


def _yaml(name: str) -> dict[str, Any]:
    """A task's yaml as a user reads it, without Hydra's defaults list."""
    import yaml

    data = yaml.safe_load((YAML_DIR / f"{name}.yaml").read_text())
    data.pop("defaults")
    return data


def _benchmarl_run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m benchmarl.run ARGS`` as a user types it, in ``cwd``."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "1"}
    out = subprocess.run(
        [sys.executable, "-m", "benchmarl.run", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return out


def test_registry_holds_the_uvms_tasks():
    from benchmarl.environments import task_config_registry
    from benchmarl_uvms import UVMSTask, UVMSTaskClass

    uvms = {k: v for k, v in task_config_registry.items() if k.startswith("uvms/")}
    assert uvms == {f"uvms/{name}": UVMSTask[name.upper()] for name in TASKS}
    assert UVMSTask.RANDOM_N2.associated_class() is UVMSTaskClass
    assert UVMSTask.env_name() == "uvms"


@pytest.mark.parametrize("name", TASKS)
def test_get_from_yaml_gives_the_yamls_values(name):
    from benchmarl_uvms import UVMSTask, UVMSTaskClass

    task = UVMSTask[name.upper()].get_from_yaml()
    assert isinstance(task, UVMSTaskClass) and task.name == name.upper()
    assert task.config == _yaml(name)
    assert UVMSTask[name.upper()].get_task().config == task.config  # no config: the yaml


def test_the_yamls_hold_their_scenarios_and_teams():
    from benchmarl_uvms import UVMSTask

    expected = {"paper": ("paper", 2), "short": ("short", 2)}
    expected |= {"random_n2": ("random", 2), "random_n4": ("random", 4)}
    for name, (scenario, n) in expected.items():
        config = UVMSTask[name.upper()].get_from_yaml().config
        assert (config["scenario"], config["n_agents"]) == (scenario, n)
        # paper has one fixed geometry: a pool there would raise in VectorEnv
        assert (config["geometry_pool"] is None) == (scenario == "paper")


def test_get_from_yaml_refuses_an_unknown_key(tmp_path):
    import yaml
    from benchmarl_uvms import UVMSTask

    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump({**_yaml("random_n2"), "max_cycle": 5}))
    with pytest.raises(TypeError, match="max_cycle"):
        UVMSTask.RANDOM_N2.get_from_yaml(str(path))
    path.write_text(yaml.safe_dump({**_yaml("random_n2"), "max_cycles": 5}))
    assert UVMSTask.RANDOM_N2.get_from_yaml(str(path)).config["max_cycles"] == 5


def test_hydra_composes_the_tasks_with_overrides_and_checks_them():
    """The search path plugin puts the yaml files where BenchMARL's own configs are."""
    from benchmarl.hydra_config import load_task_config_from_hydra
    from benchmarl_uvms import UVMSTaskClass
    from hydra import compose, initialize_config_module
    from hydra.errors import ConfigCompositionException

    with initialize_config_module(config_module="benchmarl.conf", version_base=None):
        overrides = ["algorithm=mappo", "task=uvms/random_n4", "task.max_cycles=7"]
        cfg = compose(config_name="config", overrides=overrides)
        assert cfg.task.n_agents == 4 and cfg.task.max_cycles == 7
        task = load_task_config_from_hydra(cfg.task, "uvms/random_n4")
        assert isinstance(task, UVMSTaskClass)
        assert task.config == {**_yaml("random_n4"), "max_cycles": 7}
        extra = "+task.options.constraint_mode=terminate"
        cfg = compose(config_name="config", overrides=[*overrides, extra])
        assert dict(cfg.task.options) == {"constraint_mode": "terminate"}
        # the schema (UVMSTaskConfig): a wrong type or an unknown key is refused
        for bad in ("task.max_cycles=seven", "task.max_cycle=7"):
            with pytest.raises(ConfigCompositionException):
                compose(config_name="config", overrides=[*overrides, bad])


def test_the_tasks_env_gives_one_copys_specs_and_steps():
    from benchmarl_uvms import UVMSTask

    uvms = UVMSTask.RANDOM_N2.get_from_yaml()
    uvms.config["max_cycles"] = 5
    with pytest.raises(ValueError, match="continuous"):
        uvms.get_env_fun(num_envs=3, continuous_actions=False, seed=0, device="cpu")
    env = uvms.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    assert env.vector_env.geometry_pool == 1024 and env.vector_env.num_envs == 3
    assert uvms.group_map(env) == {"uvms": ["uvms_0", "uvms_1"]}
    assert uvms.observation_spec(env)["uvms", "observation"].shape == (2, 79)
    assert "state" not in uvms.observation_spec(env).keys()
    assert uvms.action_spec(env)["uvms", "action"].shape == (2, 8)
    assert uvms.state_spec(env)["state"].shape == (20 * 2 + 19,)
    assert uvms.max_steps(env) == 5
    td = env.rollout(6, break_when_any_done=False)
    assert td["next", "uvms", "reward"].shape == (3, 6, 2, 1)
    # truncated after max_cycles, then a new episode
    assert td["next", "truncated"][:, :, 0].tolist() == [[False] * 4 + [True, False]] * 3


def test_options_must_not_repeat_the_tasks_own_keys():
    from benchmarl_uvms import UVMSTask

    uvms = UVMSTask.RANDOM_N2.get_from_yaml()
    uvms.config["options"] = {"max_cycles": 5}
    with pytest.raises(ValueError, match="max_cycles"):
        uvms.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")


def test_benchmarl_run_writes_a_checkpoint_that_reloads(tmp_path):
    """``python -m benchmarl.run`` then what ``python -m benchmarl.evaluate`` does."""
    import torch
    from benchmarl.experiment import Experiment
    from benchmarl.hydra_config import reload_experiment_from_file
    from benchmarl_uvms import UVMSTaskClass

    run = ["algorithm=mappo", "task=uvms/random_n2", "seed=1", *TINY]
    _benchmarl_run(*run, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    (checkpoint,) = (tmp_path / "run").glob("*/checkpoints/checkpoint_160.pt")
    with open(checkpoint.parents[1] / "config.pkl", "rb") as fh:
        assert type(pickle.load(fh)).__module__ == "benchmarl_uvms.tasks"  # not __main__

    experiment = reload_experiment_from_file(str(checkpoint))
    assert isinstance(experiment.task, UVMSTaskClass) and experiment.task.name == "RANDOM_N2"
    assert experiment.task.config == {**_yaml("random_n2"), "max_cycles": 10, "geometry_pool": None}
    assert experiment.seed == 1 and experiment.max_steps == 10
    assert (experiment.total_frames, experiment.n_iters_performed) == (160, 2)
    saved = torch.load(checkpoint)["loss_uvms"]
    restored = experiment.losses["uvms"].state_dict()
    assert saved.keys() == restored.keys()
    for key, value in saved.items():
        torch.testing.assert_close(restored[key], value, msg=key)

    experiment.evaluate()
    (result,) = checkpoint.parents[1].glob("*.json")
    runs = json.loads(result.read_text())["uvms"]["random_n2"]["mappo"]["seed_1"]
    evaluations = [v for k, v in runs.items() if k.startswith("step_")]
    assert len(evaluations[-1]["return"]) == 3  # experiment.evaluation_episodes

    # the same checkpoint without Hydra's metadata: BenchMARL unpickles config.pkl
    again = Experiment.reload_from_file(str(checkpoint))
    assert again.task == experiment.task and again.total_frames == 160


@pytest.mark.slow
def test_multirun_over_algorithms_and_seeds(tmp_path):
    """``benchmarl.run -m``: one job per algorithm and seed, each with its checkpoint."""
    import yaml

    sweep = ["-m", "algorithm=mappo,masac", "task=uvms/short", "seed=0,1", *TINY]
    _benchmarl_run(*sweep, f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=tmp_path)
    jobs = sorted((tmp_path / "sweep").glob("*/*/checkpoints/checkpoint_160.pt"))
    names = sorted(path.parents[1].name.split("_")[0] for path in jobs)
    assert names == ["mappo", "mappo", "masac", "masac"]
    for path in jobs:
        overrides = yaml.safe_load((path.parents[2] / ".hydra" / "overrides.yaml").read_text())
        assert "task=uvms/short" in overrides
