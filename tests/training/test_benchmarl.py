"""BenchMARL's uvms tasks (``baselines.benchmarl_tasks`` and the Hydra plugin
``hydra_plugins.uvms_coop_benchmarl``) as a BenchMARL user runs them: the registry,
``get_from_yaml``, the Hydra configs, the env's specs and infos, a ``benchmarl.run`` whose
checkpoint ``reload_experiment_from_file`` restores, the episodes' metrics in the scalars and
marl-eval JSON (``run_experiment``), a checkpoint's evaluation that replays the run's, its
policy in the project's evaluator (``--policy benchmarl:PATH``), and (slow) a multirun over
MAPPO and MASAC. The runs are tiny: a few hundred frames of 10-step episodes.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("benchmarl", reason="the learn extra installs BenchMARL")

# the tasks' yaml files in this checkout (the editable install reads these)
YAML_DIR = Path(__file__).resolve().parents[2] / "baselines/benchmarl_tasks/conf/task/uvms"
TASKS_MODULE = "baselines.benchmarl_tasks"


TASKS = ("paper", "short", *(f"random_n{n}" for n in range(2, 7)))
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


def _benchmarl_run(
    *args: str, cwd: Path, module: str = "benchmarl.run"
) -> subprocess.CompletedProcess:
    """``python -m benchmarl.run ARGS`` (or ``module``) as a user types it, in ``cwd``."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "1"}
    out = subprocess.run(
        [sys.executable, "-m", module, *args],
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

    from baselines.benchmarl_tasks import UVMSTask, UVMSTaskClass

    uvms = {k: v for k, v in task_config_registry.items() if k.startswith("uvms/")}
    assert uvms == {f"uvms/{name}": UVMSTask[name.upper()] for name in TASKS}
    assert UVMSTask.RANDOM_N2.associated_class() is UVMSTaskClass
    assert UVMSTask.env_name() == "uvms"


@pytest.mark.parametrize("name", TASKS)
def test_get_from_yaml_gives_the_yamls_values(name):
    from baselines.benchmarl_tasks import UVMSTask, UVMSTaskClass

    task = UVMSTask[name.upper()].get_from_yaml()
    assert isinstance(task, UVMSTaskClass) and task.name == name.upper()
    assert task.config == _yaml(name)
    assert UVMSTask[name.upper()].get_task().config == task.config  # no config: the yaml


def test_the_yamls_hold_their_scenarios_and_teams():
    from baselines.benchmarl_tasks import UVMSTask

    expected = {"paper": ("paper", 2), "short": ("short", 2)}
    expected |= {f"random_n{n}": ("random", n) for n in range(2, 7)}
    for name, (scenario, n) in expected.items():
        config = UVMSTask[name.upper()].get_from_yaml().config
        assert (config["scenario"], config["n_agents"]) == (scenario, n)
        # paper has one fixed geometry: a pool there would raise in VectorEnv
        assert (config["geometry_pool"] is None) == (scenario == "paper")


def test_get_from_yaml_refuses_an_unknown_key(tmp_path):
    import yaml

    from baselines.benchmarl_tasks import UVMSTask

    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump({**_yaml("random_n2"), "max_cycle": 5}))
    with pytest.raises(TypeError, match="max_cycle"):
        UVMSTask.RANDOM_N2.get_from_yaml(str(path))
    path.write_text(yaml.safe_dump({**_yaml("random_n2"), "max_cycles": 5}))
    assert UVMSTask.RANDOM_N2.get_from_yaml(str(path)).config["max_cycles"] == 5


def test_hydra_composes_the_tasks_with_overrides_and_checks_them():
    """The search path plugin puts the yaml files where BenchMARL's own configs are."""
    from benchmarl.hydra_config import load_task_config_from_hydra
    from hydra import compose, initialize_config_module
    from hydra.errors import ConfigCompositionException

    from baselines.benchmarl_tasks import UVMSTaskClass

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
    from baselines.benchmarl_tasks import UVMSTask

    uvms = UVMSTask.RANDOM_N2.get_from_yaml()
    uvms.config["max_cycles"] = 5
    with pytest.raises(ValueError, match="continuous"):
        uvms.get_env_fun(num_envs=3, continuous_actions=False, seed=0, device="cpu")
    env = uvms.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    assert env.vector_env.geometry_pool == 1024 and env.vector_env.num_envs == 3
    assert uvms.group_map(env) == {"uvms": ["uvms_0", "uvms_1"]}
    assert uvms.observation_spec(env)["uvms", "observation"].shape == (2, 79)
    assert "state" not in uvms.observation_spec(env).keys()
    assert "info" not in uvms.observation_spec(env)["uvms"].keys()  # never a model's input
    info = uvms.info_spec(env)["uvms", "info"]
    assert {"cost", "success", "clean_success", "violation_periods", "episode_cost"} <= set(
        info.keys()
    )
    assert info["violations_collision"].shape == (2,)
    assert uvms.action_spec(env)["uvms", "action"].shape == (2, 8)
    assert uvms.state_spec(env)["state"].shape == (20 * 2 + 19,)
    assert uvms.max_steps(env) == 5
    td = env.rollout(6, break_when_any_done=False)
    assert td["next", "uvms", "reward"].shape == (3, 6, 2, 1)
    # truncated after max_cycles, then a new episode
    assert td["next", "truncated"][:, :, 0].tolist() == [[False] * 4 + [True, False]] * 3
    # the collection scalars of the ended episodes, from their last step's infos
    logged = uvms.log_info(td)
    assert logged["collection/uvms/episode/count"] == 3.0
    ended = td["next", "uvms", "info"][:, 4]
    assert logged["collection/uvms/episode/episode_steps"] == 5.0
    expected = ended["violation_periods"].double().mean().item()
    assert logged["collection/uvms/episode/violation_periods"] == pytest.approx(expected)
    assert uvms.log_info(td[:, :4]) == {}  # none ended


def test_the_task_renders_copy_0_every_render_every_steps():
    from types import SimpleNamespace

    from baselines.benchmarl_tasks import UVMSTask

    uvms = UVMSTask.SHORT.get_from_yaml()
    env = uvms.get_env_fun(num_envs=2, continuous_actions=True, seed=0, device="cpu")()
    assert not uvms.has_render(env)  # the yamls' default: no video (README.md, "Videos")
    uvms.config["render_every"] = 2
    assert uvms.has_render(env)
    experiment = SimpleNamespace(task=uvms)
    td = env.reset()
    frames = []
    for _ in range(3):
        frames.append(uvms.render_callback(experiment, env, td))
        env.rand_step()
    assert frames[0].shape == (360, 720, 3) and frames[0].dtype == np.uint8
    assert frames[1] is frames[0] and frames[2] is not frames[0]


def test_options_must_not_repeat_the_tasks_own_keys():
    from baselines.benchmarl_tasks import UVMSTask

    uvms = UVMSTask.RANDOM_N2.get_from_yaml()
    uvms.config["options"] = {"max_cycles": 5}
    with pytest.raises(ValueError, match="max_cycles"):
        uvms.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")


def test_benchmarl_run_writes_a_checkpoint_that_reloads(tmp_path):
    """``python -m benchmarl.run`` then what ``python -m benchmarl.evaluate`` does."""
    import torch
    from benchmarl.experiment import Experiment
    from benchmarl.hydra_config import reload_experiment_from_file

    from baselines.benchmarl_tasks import UVMSTaskClass

    run = ["algorithm=mappo", "task=uvms/random_n2", "seed=1", *TINY]
    _benchmarl_run(*run, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    (checkpoint,) = (tmp_path / "run").glob("*/checkpoints/checkpoint_160.pt")
    with open(checkpoint.parents[1] / "config.pkl", "rb") as fh:
        assert type(pickle.load(fh)).__module__ == f"{TASKS_MODULE}.tasks"  # not __main__

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


# TINY with an evaluation after each of the two iterations (steps 1 and 2 of the JSON)
EVALUATED = [
    *(o for o in TINY if not o.startswith("experiment.evaluation=")),
    "experiment.evaluation=true",
    "experiment.evaluation_interval=80",
]


@pytest.fixture(scope="module")
def mappo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``python -m baselines.benchmarl_tasks.run_experiment`` of MAPPO on uvms/short, seed 1:
    the Hydra run folder (one experiment folder inside)."""
    root = tmp_path_factory.mktemp("mappo")
    run = ["algorithm=mappo", "task=uvms/short", "seed=1", *EVALUATED]
    _benchmarl_run(
        *run, f"hydra.run.dir={root / 'run'}", cwd=root, module=f"{TASKS_MODULE}.run_experiment"
    )
    return root / "run"


def _experiment(run: Path) -> Path:
    (folder,) = run.glob("mappo_short_*")
    return folder


def test_the_logs_hold_the_episodes_and_a_checkpoint_replays_the_evaluation(mappo_run):
    from baselines.benchmarl_tasks.evaluate_checkpoint import main as evaluate_main

    folder = _experiment(mappo_run)
    scalars = folder / folder.name / "scalars"
    for name in (
        "collection_uvms_episode_success",  # log_info: the episodes ended in the batch
        "collection_uvms_episode_clean_success",
        "collection_uvms_episode_violation_periods",
        "collection_uvms_episode_violations_joint_speed",
        "collection_uvms_info_cost",  # BenchMARL's mean over the frames
        "eval_uvms_episode_success",  # EpisodeMetrics: the evaluation's episodes
        "eval_uvms_episode_clean_success",
        "eval_uvms_episode_violation_periods",
        "eval_uvms_episode_episode_cost",
    ):
        assert (scalars / f"{name}.csv").exists(), name
    (result,) = folder.glob("*.json")
    runs = json.loads(result.read_text())["uvms"]["short"]["mappo"]
    assert list(runs) == ["seed_1"] and sorted(runs["seed_1"]) == [
        "absolute_metrics",
        "step_1",
        "step_2",
    ]
    last = runs["seed_1"]["step_2"]
    for key in ("return", "success", "clean_success", "violation_periods", "episode_cost"):
        assert len(last[key]) == 3, key  # experiment.evaluation_episodes
    assert all(0 < steps <= 10 for steps in last["episode_steps"])
    assert set(last["success"]) <= {0.0, 1.0}
    kinds = sum(last[k][0] for k in last if k.startswith("violations_"))
    assert kinds == last["violation_periods"][0]
    # a checkpoint's evaluation, in a new process, plays the run's evaluation again
    evaluate_main([str(folder / "checkpoints" / "checkpoint_160.pt")])
    again = json.loads(result.read_text())["uvms"]["short"]["mappo"]["seed_1"]["step_2"]
    assert again.keys() == last.keys()
    for key, values in last.items():  # the same episodes; float32 sums of another process
        assert again[key] == pytest.approx(values, rel=1e-5, abs=1e-6), key


def test_benchmarl_policy_acts_as_the_experiments_policy(mappo_run):
    import torch
    from benchmarl.hydra_config import reload_experiment_from_file
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    import uvms_env
    from baselines.loaders.benchmarl_policy import BenchMARLPolicy
    from uvms_env.policy import AgentSpec

    checkpoint = _experiment(mappo_run) / "checkpoints" / "checkpoint_160.pt"
    for path in (mappo_run, _experiment(mappo_run), checkpoint):
        assert BenchMARLPolicy.find(path) == checkpoint
    run = BenchMARLPolicy.training_run(mappo_run)
    assert (run.algorithm, run.seed, run.frames, run.task) == ("mappo", 1, 160, "short")

    env = uvms_env.parallel_env("short")
    obs, _ = env.reset(seed=3)
    robots = [BenchMARLPolicy(AgentSpec.from_scenario(env.scenario, i), checkpoint) for i in (0, 1)]
    mine = np.stack([p.act(obs[f"uvms_{i}"]) for i, p in enumerate(robots)])
    experiment = reload_experiment_from_file(str(checkpoint))
    rows = torch.as_tensor(np.stack([obs["uvms_0"], obs["uvms_1"]]))
    td = TensorDict({"uvms": TensorDict({"observation": rows}, [2])}, [])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        theirs = experiment.policy(td)["uvms", "action"].numpy()
    np.testing.assert_allclose(mine, theirs, rtol=1e-5, atol=1e-6)


def test_the_evaluator_files_a_checkpoint_under_its_training_run(mappo_run, tmp_path):
    from baselines.evaluate import main as evaluate_main
    from baselines.evaluation import marl_eval

    path = tmp_path / "marl.json"
    common = ["--scenario", "short", "--episodes", "2", "--max-cycles", "5", "--workers", "1"]
    policies = ["--policy", f"benchmarl:{mappo_run}", "--policy", "zero"]
    evaluate_main([*policies, *common, "--out", str(tmp_path / "eval")])
    rows = (tmp_path / "eval" / "episodes.csv").read_text()
    assert rows.count("benchmarl:") == 2 and "Error" not in rows
    evaluate_main(
        [*policies, *common, "--out", str(tmp_path / "e2"), "--marl-eval-json", str(path)]
    )
    ours = json.loads(path.read_text())
    algos = ours["uvms"]["short"]
    assert set(algos) == {"mappo", "zero"}  # by what was trained
    assert set(algos["mappo"]) == set(algos["zero"]) == {"seed_1"}  # the training seed
    (benchmarls,) = _experiment(mappo_run).glob("*.json")
    theirs = json.loads(benchmarls.read_text())
    # one run evaluated by both tools, on different episodes: the merge refuses
    with pytest.raises(ValueError, match="mappo/seed_1"):
        marl_eval.merge(theirs, ours, final=True)
    # BenchMARL's evaluations of its runs, the evaluator's of the others at their seeds
    del ours["uvms"]["short"]["mappo"]
    runs = marl_eval.merge(theirs, ours, final=True)["uvms"]["short"]
    assert set(runs) == {"mappo", "zero"} and set(runs["zero"]) == {"seed_1"}
    metrics = set(runs["zero"]["seed_1"]["step_0"])
    assert {"return", "uvms_return", "success", "violation_periods"} <= metrics
    assert metrics == set(runs["mappo"]["seed_1"]["step_0"]) | {"elapsed_time"}


def test_without_benchmarl_the_loader_names_the_install(tmp_path, monkeypatch):
    from baselines.evaluation import marl_eval
    from baselines.loaders.sources import PolicySource

    checkpoints = tmp_path / "mappo_short" / "checkpoints"
    checkpoints.mkdir(parents=True)
    (checkpoints / "checkpoint_160.pt").write_bytes(b"")
    (checkpoints.parent / "config.pkl").write_bytes(b"")
    factory = PolicySource.parse(f"benchmarl:{tmp_path}").factory(0)  # found
    monkeypatch.setitem(sys.modules, "benchmarl", None)  # an install without the learn extra
    with pytest.raises(ImportError, match=r"learn\]"):
        factory(None)
    label = f"benchmarl:{tmp_path}"
    assert marl_eval.run_identity(label) == marl_eval.RunIdentity(label, None)
