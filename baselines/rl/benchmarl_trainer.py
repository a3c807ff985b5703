"""BenchMARL as the TorchRL trainer of ``baselines.train`` (``--library benchmarl``): MAPPO,
IPPO or MASAC from BenchMARL's ``Experiment`` on the uvms tasks of
``baselines.benchmarl_tasks`` (the batched env's TorchRL view), under the project's run folder.

    python -m baselines.train --library benchmarl --algo mappo --scenario random --n-agents 2 \\
        --robot-steps 2000000 --eval-every 200000 --out runs/benchmarl_mappo

BenchMARL collects, learns, logs (its csv scalars) and checkpoints; this module only maps
the shared options onto its configs and reports each iteration to ``baselines.runs``:

* the task: the scenario's ``uvms/<task>`` (``random_n<N>`` for the random family) with the
  run's environment options, precision, threads, geometry pool and backend;
* the budget: ``--robot-steps`` over N robots in whole iterations of BenchMARL's collected
  frames (6,000 rounded up to whole steps of the ``--num-envs`` copies, unless ``--hp``
  sets them); ``--checkpoint-every`` becomes BenchMARL's ``checkpoint_interval``;
* ``--seed``: the experiment's seed (a resumed run's moves on, as in every library);
  ``--resume RUN``: BenchMARL's ``restore_file`` (the run's latest checkpoint);
* ``--cost``: PPO-Lagrangian's penalty (``baselines.lagrangian``) subtracted from each
  robot's reward in the collected batch, before BenchMARL computes its advantages;
* ``--backend cuda``/``--device``: the copies, the batches and the updates on one GPU.

The run folder holds BenchMARL's experiment folder (``config.pkl``, ``checkpoints/``, its
scalars), and ``checkpoints/`` + ``config.pkl`` of the final state, which ``--policy
benchmarl:RUN`` loads (``baselines.loaders.benchmarl_policy``). Reference: docs/rl.md,
"The BenchMARL trainer"; docs/benchmarl.md.

May import: numpy, torch, tensordict and benchmarl (inside the training functions),
``baselines.benchmarl_tasks``, ``baselines.runs``, ``baselines.lagrangian``,
``baselines.registry``, ``baselines.command_line`` (the flags' types),
``baselines.loaders.benchmarl_policy`` and ``baselines.loaders.saved`` (the checkpoint layout,
the run record) and ``uvms_env``.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
from dataclasses import fields
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.command_line import positive_int
from baselines.lagrangian import CONSTRAINTS, Lagrangian
from baselines.loaders.benchmarl_policy import CHECKPOINT, BenchMARLPolicy
from baselines.loaders.saved import read_config
from baselines.registry import LIBRARIES
from baselines.runs import DTYPES, Run, add_step_arguments, seeded_pool
from uvms_env.vector.batched_simulator import BACKENDS

ALGOS = LIBRARIES["benchmarl"].algos
# BenchMARL's defaults (its yaml files), changed where this env is measured faster
# (docs/benchmarl.md, "Fast settings": 3-5x per iteration): fewer, larger minibatch passes.
HYPERPARAMETERS: dict[str, Any] = {
    "experiment.on_policy_n_minibatch_iters": 10,
    "experiment.on_policy_minibatch_size": 1000,
}
SECTIONS = ("experiment", "algorithm", "model", "critic_model")
FRAMES_PER_BATCH = 6000  # BenchMARL's collected frames per iteration, on and off policy
# 60 copies: 100 steps each of BenchMARL's 6,000 frames; a seeded family's episodes take the
# bank's first 1,024 geometries, as in the other trainers.
DEFAULTS: dict[str, Any] = {"num_envs": 60, "geometry_pool": 1024}
SEVERAL_TEAM_SIZES = False  # a BenchMARL task has one group of a fixed size
# the experiment settings the shared options own: --hp may not set them
OWNED = {
    "max_n_frames": "--robot-steps",
    "max_n_iters": "--robot-steps",
    "on_policy_n_envs_per_worker": "--num-envs",
    "off_policy_n_envs_per_worker": "--num-envs",
    "checkpoint_interval": "--checkpoint-every",
    "restore_file": "--resume",
    "save_folder": "--out",
    "sampling_device": "--device",
    "train_device": "--device",
    "buffer_device": "--device",
}
CONFIG_FILE = "config.pkl"
MULTIPLIER = "lagrangian_multiplier"  # PPO-Lagrangian's multiplier in BenchMARL's checkpoints
OPTIONS_NOTE = (
    "--hp SECTION.KEY=JSON sets a field of BenchMARL's config, SECTION one of "
    f"{', '.join(SECTIONS)} (e.g. experiment.lr=0.0003, algorithm.entropy_coef=0.01, "
    "model.num_cells=[64,64]); defaults: BenchMARL's yaml files, and "
    + ", ".join(f"{k}={v}" for k, v in HYPERPARAMETERS.items())
)
# the uvms task of each scenario family (the random family: by team size)
TASK_OF_SCENARIO = {"paper": "paper", "short": "short"}


def add_arguments(g: Any) -> None:
    """The BenchMARL trainer's own options."""
    g.add_argument("--backend", choices=BACKENDS, default="cpu", help="the VectorEnv backend")
    g.add_argument(
        "--device",
        default=None,
        help="GPU index (default 0 with --backend cuda) or cpu: where the env's tensors, "
        "the networks and the updates live",
    )
    add_step_arguments(g)
    g.add_argument("--torch-threads", type=positive_int, default=1)


def configs(algo: str) -> dict[str, Any]:
    """BenchMARL's configs of ``algo`` from its yaml files, by ``--hp`` section."""
    from benchmarl.algorithms import IppoConfig, MappoConfig, MasacConfig
    from benchmarl.experiment import ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    algorithm = {"mappo": MappoConfig, "ippo": IppoConfig, "masac": MasacConfig}[algo]
    return {
        "experiment": ExperimentConfig.get_from_yaml(),
        "algorithm": algorithm.get_from_yaml(),
        "model": MlpConfig.get_from_yaml(),
        "critic_model": MlpConfig.get_from_yaml(),
    }


def split_key(key: str) -> tuple[str, str]:
    section, _, name = key.partition(".")
    if section not in SECTIONS or not name:
        raise ValueError(f"--hp {key!r}: name SECTION.KEY, SECTION one of {SECTIONS}")
    return section, name


def check_options(settings: Any, algo: str, args: argparse.Namespace) -> None:
    """ValueError naming the option where this trainer cannot honour ``settings``
    (``baselines.runs.RunSettings``) or its own options ``args``: before any work."""
    if algo not in ALGOS:
        raise ValueError(f"benchmarl trains {ALGOS}, not {algo!r}")
    if args.backend not in BACKENDS:
        raise ValueError(f"--backend must be one of {BACKENDS}, got {args.backend!r}")
    if args.dtype not in DTYPES:
        raise ValueError(f"--dtype must be one of {DTYPES}, got {args.dtype!r}")
    parse_device(args.device, args.backend)
    for flag, values in (("--n-agents", settings.team_sizes), ("--object", settings.objects)):
        if len(values) > 1:  # baselines.train refuses it first, naming the libraries that can
            raise ValueError(f"{flag} with several values: a BenchMARL task has one group")
    task_name(settings.scenario, settings.env_options())
    try:
        sections = configs(algo)
    except ImportError as exc:
        raise ValueError(
            f'--library benchmarl needs BenchMARL: pip install -e ".[learn]" ({exc})'
        ) from exc
    for key in settings.hyperparameters:
        section, name = split_key(key)
        known = [f.name for f in fields(sections[section])]
        if name not in known:
            raise ValueError(f"--hp {key!r}: {section} has no {name!r}; known: {known}")
        if section == "experiment" and name in OWNED:
            raise ValueError(f"--hp {key!r}: set by {OWNED[name]}")
    if settings.resume is not None:
        resume_file(Path(settings.resume))


def parse_device(text: str | int | None, backend: str) -> str:
    """``--device``: a GPU index or ``cpu`` -> a torch device name; default GPU 0 for the
    CUDA backend."""
    if text is None:
        return "cuda:0" if backend == "cuda" else "cpu"
    text = str(text)
    index = text[5:] if text.startswith("cuda:") else text
    if index.isdigit():
        return f"cuda:{int(index)}"
    if text != "cpu":
        raise ValueError(f"--device must be a GPU index or 'cpu', got {text!r}")
    return "cpu"


def task_name(scenario: str, options: dict[str, Any]) -> str:
    """The uvms task a run trains on: ``paper``, ``short``, ``random_n<N>``."""
    if scenario == "random":
        n = int(options.get("n_agents", 2))
        if not 2 <= n <= 6:
            raise ValueError(f"--n-agents {n}: the random tasks have 2 to 6 robots")
        return f"random_n{n}"
    if scenario not in TASK_OF_SCENARIO:
        raise ValueError(f"no BenchMARL task for --scenario {scenario!r}")
    return TASK_OF_SCENARIO[scenario]


def resume_file(path: Path) -> Path:
    """The checkpoint ``--resume PATH`` continues: a checkpoint; for a run folder, the latest
    of BenchMARL's experiment folder in it (config.json's ``experiment_folder``: the run
    goes on writing there), else of the folder itself (``BenchMARLPolicy.find``)."""
    if path.is_file():
        if CHECKPOINT.fullmatch(path.name) is None:
            raise ValueError(f"--resume {path}: not a BenchMARL checkpoint_<frames>.pt")
        return path
    name = read_config(path).get("library_settings", {}).get("experiment_folder")
    if name and (path / name / "checkpoints").is_dir():
        return BenchMARLPolicy.find(path / name)
    return BenchMARLPolicy.find(path)


class Trainer:
    """BenchMARL's ``Experiment`` under a ``baselines.runs.Run`` (``baselines.runs.Trainer``)."""

    def __init__(self, run: Run, algo: str, args: argparse.Namespace) -> None:
        check_options(run.settings, algo, args)
        self.run, self.algo, self.args = run, algo, args
        self.hp = {**HYPERPARAMETERS, **run.settings.hyperparameters}
        self.experiment: Any = None
        self.lagrangian: Lagrangian | None = None
        self.n = 1  # robots per copy
        self.returns: list[float] = []
        self.lengths: list[float] = []
        self.ends: list[str] = []
        self._in_iteration = False  # between a batch and BenchMARL's count of its iteration
        self._ran = False

    def build(self) -> dict[str, Any]:
        import torch
        from benchmarl.experiment import Callback, Experiment

        from baselines.benchmarl_tasks import UVMSTask
        from baselines.benchmarl_tasks.episode_logs import EpisodeMetrics

        s, a = self.run.settings, self.args
        torch.set_num_threads(a.torch_threads)
        device = parse_device(a.device, a.backend)
        options = s.env_options()
        name = task_name(s.scenario, options)
        task = UVMSTask[name.upper()].get_from_yaml()
        own = set(task.config) - {"scenario", "options"}
        task.config.update(
            {key: value for key, value in options.items() if key in own},
            dtype=a.dtype,
            threads=a.env_threads,
            geometry_pool=seeded_pool(s.scenario, s.overrides, s.geometry_pool),
            backend=a.backend,
            options={k: v for k, v in options.items() if k not in own},
        )
        sections = configs(self.algo)
        for key, value in self.hp.items():
            section, field = split_key(key)
            setattr(sections[section], field, value)
        config = sections["experiment"]
        prefix = "on_policy" if sections["algorithm"].on_policy() else "off_policy"
        key = f"experiment.{prefix}_collected_frames_per_batch"
        # whole steps of every copy: BenchMARL's 6,000 frames rounded up, unless --hp sets them
        frames = int(self.hp.get(key, s.num_envs * math.ceil(FRAMES_PER_BATCH / s.num_envs)))
        if frames % s.num_envs:
            raise ValueError(f"--hp {key}={frames}: not whole steps of {s.num_envs} copies")
        self.n = int(task.config["n_agents"])
        per_batch = frames * self.n
        iterations = math.ceil(s.robot_steps / per_batch)
        every = math.ceil(s.checkpoint_every / per_batch) if s.checkpoint_every else 0
        restore = resume_file(Path(s.resume)) if s.resume is not None else None
        values = {
            f"{prefix}_collected_frames_per_batch": frames,
            f"{prefix}_n_envs_per_worker": s.num_envs,
            "max_n_frames": iterations * frames,
            "max_n_iters": None,
            "checkpoint_interval": every * frames,
            "checkpoint_at_end": True,
            "loggers": self.hp.get("experiment.loggers", ["csv"]),  # BenchMARL's: wandb too
            # the run's evaluations are baselines.evaluate's (--eval-every); BenchMARL's own
            # with --hp experiment.evaluation=true (its interval: a multiple of the frames)
            "evaluation": self.hp.get("experiment.evaluation", False),
            "render": self.hp.get("experiment.render", False),
            "save_folder": str(self.run.folder),
            "restore_file": None if restore is None else str(restore),
            "sampling_device": device,
            "train_device": device,
            "buffer_device": device,
        }
        for field, value in values.items():
            setattr(config, field, value)
        if s.cost is not None:
            self.lagrangian = Lagrangian(s.cost, s.num_envs * self.n)
        trainer = self

        class RunHooks(Callback):
            """Each iteration to the run: its batch (``Trainer.collected``) and its end."""

            def on_batch_collected(self, batch: Any) -> None:
                trainer.collected(batch)

            def on_train_end(self, training_td: Any, group: str) -> None:
                trainer.iteration_done()

            def on_state_dict(self, state_dict: dict[str, Any]) -> None:
                if trainer.lagrangian is not None:
                    state_dict[MULTIPLIER] = trainer.lagrangian.multiplier

            def on_load_state_dict(self, state_dict: dict[str, Any]) -> None:
                if trainer.lagrangian is not None and MULTIPLIER in state_dict:
                    trainer.lagrangian.multiplier = float(state_dict[MULTIPLIER])

        hooks = RunHooks()
        self.experiment = experiment = Experiment(
            task=task,
            algorithm_config=sections["algorithm"],
            model_config=sections["model"],
            critic_model_config=sections["critic_model"],
            seed=self.run.env_seed,
            config=config,
            callbacks=[EpisodeMetrics()],
        )
        # after the experiment pickled its callbacks into config.pkl: the hooks serve this
        # run only (a restored checkpoint's experiment gets EpisodeMetrics alone)
        hooks.experiment = experiment
        experiment.callbacks = [*experiment.callbacks, hooks]
        if restore is not None and self.lagrangian is not None:
            state = torch.load(restore, map_location="cpu", weights_only=False)
            hooks.on_load_state_dict(state)  # BenchMARL restored before the hooks joined
        self.run.config["hardware"].update(hardware(device))
        return {
            "task": f"uvms/{name}",
            "task_config": dict(task.config),
            "backend": a.backend,
            "device": device,
            "dtype": a.dtype,
            "env_threads": a.env_threads,
            "robots": s.num_envs * self.n,
            "hyperparameters": self.hp,
            "frames_per_iteration": frames,
            "robot_steps_per_iteration": per_batch,
            "experiment_folder": experiment.folder_name.name,
            "torch_threads": torch.get_num_threads(),
        }

    @property
    def robot_steps(self) -> int:
        return int(self.experiment.total_frames) * self.n

    def learn(self) -> int:
        experiment = self.experiment
        if experiment.n_iters_performed >= experiment.config.get_max_n_iters(experiment.on_policy):
            return self.robot_steps  # a resumed run already at its budget
        self.run.begin(experiment.config.collected_frames_per_batch(experiment.on_policy) * self.n)
        self._ran = True
        experiment.run()  # closes the experiment (collector, loggers) at its end
        return self.robot_steps

    def save(self, folder: Path) -> None:
        """``folder/checkpoints/checkpoint_<frames>.pt`` and ``folder/config.pkl``, the
        layout BenchMARL restores from: the run folder gets a copy of BenchMARL's last
        checkpoint; an evaluation snapshot the experiment's state as it stands, without
        the replay buffers (a policy's evaluation needs none). The copy of the last
        checkpoint is a hard link where the file system has them: an off-policy
        checkpoint holds the replay buffer (MASAC's default of 10^6 frames: 2.5 GB at
        N = 2)."""
        import torch

        experiment = self.experiment
        checkpoints = folder / "checkpoints"
        shutil.rmtree(checkpoints, ignore_errors=True)
        checkpoints.mkdir(parents=True)
        name = f"checkpoint_{experiment.total_frames}.pt"
        shutil.copy2(experiment.folder_name / CONFIG_FILE, folder / CONFIG_FILE)
        last = experiment.folder_name / "checkpoints" / name
        if not self._in_iteration and last.exists():
            _link_or_copy(last, checkpoints / name)
            return
        state = experiment.state_dict()
        for key in [k for k in state if k.startswith("buffer_")]:
            state[key] = None
        if self._in_iteration:  # BenchMARL counts the iteration after its hooks
            state["state"]["n_iters_performed"] = experiment.n_iters_performed + 1
        torch.save(state, checkpoints / name)

    def results(self) -> dict[str, Any]:
        e = self.experiment
        return {"frames": int(e.total_frames), "iterations": int(e.n_iters_performed)}

    def close(self) -> None:
        if self.experiment is not None and not self._ran:  # run() closes it itself
            self.experiment.close()
            self._ran = True

    # -- the iteration's hooks (RunHooks) ---------------------------------------------------
    def collected(self, batch: Any) -> None:
        """A batch is in, BenchMARL's advantages not yet computed: the iteration's ended
        episodes (the team return as robot 0 receives it, unpenalized), and the cost
        penalty subtracted from the rewards."""
        from uvms_env.env.infos import EPISODE_END_NAMES
        from uvms_env.vector.torchrl_env import GROUP

        self._in_iteration = True
        done = batch.get(("next", "done"))[..., 0]  # (K, T)
        info = batch.get(("next", GROUP, "info"))
        team = batch.get(("next", GROUP, "episode_reward"))[..., 0, 0]
        self.returns = team[done].tolist()
        self.lengths = info.get("episode_steps")[..., 0][done].tolist()
        self.ends = [EPISODE_END_NAMES[int(c)] for c in info.get("episode_end")[..., 0][done]]
        if self.lagrangian is not None:
            reward = batch.get(("next", GROUP, "reward"))
            batch.set(("next", GROUP, "reward"), reward - self._penalties(done, info))

    def _penalties(self, done: Any, info: Any) -> Any:
        """(K, T, N, 1) the multiplier times each robot's cost in the batch's T steps
        (``baselines.lagrangian``), at the multiplier the batch was collected with."""
        import torch

        assert self.lagrangian is not None
        g = torch.stack([info.get(f"constraint_{kind}") for kind in CONSTRAINTS], -1)
        g, count = g.cpu().numpy(), info.get("cost").cpu().numpy()  # (K, T, N, 8), (K, T, N)
        ended = done.cpu().numpy()
        k, steps, n = count.shape
        cost = np.stack(
            [
                self.lagrangian.penalize(g[:, t], count[:, t], np.repeat(ended[:, t], n))
                for t in range(steps)
            ],
            1,
        )  # (K N, T)
        cost = cost.reshape(k, n, steps).transpose(0, 2, 1)[..., None]
        return torch.as_tensor(
            self.lagrangian.multiplier * cost, dtype=torch.float32, device=done.device
        )

    def iteration_done(self) -> None:
        cost = multiplier = None
        if self.lagrangian is not None:
            cost = self.lagrangian.end_rollout()
            multiplier = self.lagrangian.multiplier
        run, steps = self.run, self.robot_steps
        run.iteration(
            steps,
            returns=self.returns,
            lengths=self.lengths,
            episode_cost=cost,
            multiplier=multiplier,
            ends=self.ends,
        )
        # no checkpoint of ours: BenchMARL writes its own (``checkpoint_interval``)
        if run.due("eval_every", steps):
            with run.apart():
                self.save(run.snapshot)
                run.evaluate_snapshot(steps)
        self._in_iteration = False


def hardware(device: str) -> dict[str, Any]:
    """The libraries and the GPU, added to the run's hardware record."""
    from importlib.metadata import version

    import torch

    info: dict[str, Any] = {
        "torch": torch.__version__,
        "torchrl": version("torchrl"),
        "benchmarl": version("benchmarl"),
    }
    if device.startswith("cuda"):
        info["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return info


def _link_or_copy(source: Path, target: Path) -> None:
    """``target`` the same file as ``source`` (a hard link), a copy where the file system
    links none: BenchMARL writes each checkpoint once, under a new name, and removes old
    ones by unlinking them, so the link keeps its content."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)
