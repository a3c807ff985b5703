"""A BenchMARL checkpoint's policy as a per-robot policy (``--policy benchmarl:PATH``), so that
the evaluator plays it on the ladder's episodes beside the expert and the other baselines.

PATH: a checkpoint (``<experiment>/checkpoints/checkpoint_<frames>.pt``), an experiment
folder, a ``baselines.train --library benchmarl`` run folder (its own ``checkpoints/``) or
the Hydra run folder that holds one experiment folder (their latest checkpoint). BenchMARL restores
the experiment (``Experiment.reload_from_file``, its own config.pkl beside the checkpoints,
patched to one env copy, no loggers, and a scratch folder for what it writes), and the
robot acts with BenchMARL's policy under TorchRL's deterministic exploration, as BenchMARL's
own evaluation does: the robot's observation goes in, its action comes out. The task's
``options`` give the priors and the channel (``baselines.loaders.saved``).

BenchMARL comes with the ``learn`` extra; without it loading raises ``ImportError`` naming
that install.

May import: numpy, torch, tensordict, torchrl and benchmarl (inside the loader),
``baselines.loaders.saved`` and ``uvms_env``.
"""

from __future__ import annotations

import pickle
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy, load_once, options_record
from uvms_env.policy import AgentSpec

INSTALL = (
    "BenchMARL is not installed here: --policy benchmarl:PATH needs the learn extra "
    '(pip install -e ".[learn]" -c constraints.txt)'
)
CHECKPOINT = re.compile(r"checkpoint_(\d+)\.pt")
GROUP = "uvms"  # the tasks' agent group (uvms_env.vector.torchrl_env.GROUP)
# the restored experiment's settings that matter for acting only: one copy, nothing logged
PATCH: dict[str, Any] = {
    # on the host, whatever device trained it (the evaluator plays single envs on the CPU)
    "sampling_device": "cpu",
    "train_device": "cpu",
    "buffer_device": "cpu",
    "restore_map_location": "cpu",
    "loggers": [],
    "create_json": False,
    "render": False,
    "evaluation_episodes": 1,
    "on_policy_n_envs_per_worker": 1,
    "off_policy_n_envs_per_worker": 1,
}


@dataclass(frozen=True)
class TrainingRun:
    """What trained a checkpoint: BenchMARL's algorithm name (``mappo``), the experiment's
    seed, its frames, the task's name and config."""

    algorithm: str
    seed: int
    frames: int
    task: str
    task_config: dict[str, Any]


def _frames(path: Path) -> int:
    match = CHECKPOINT.fullmatch(path.name)
    return int(match.group(1)) if match else -1


def read_config(checkpoint: Path) -> TrainingRun:
    """The experiment's config.pkl (BenchMARL's pickles: task, task config, algorithm
    config, model config, seed, ...) beside ``checkpoints/``. Needs BenchMARL and the
    task's package to unpickle."""
    try:
        import benchmarl  # noqa: F401
    except ImportError as exc:
        raise ImportError(INSTALL) from exc
    with open(Path(checkpoint).parents[1] / "config.pkl", "rb") as fh:
        task, task_config, algorithm_config = (pickle.load(fh) for _ in range(3))
        pickle.load(fh)  # the model config
        seed = pickle.load(fh)
    algorithm = algorithm_config.associated_class().__name__.lower()
    return TrainingRun(algorithm, int(seed), _frames(checkpoint), task.name.lower(), task_config)


def load_policy(checkpoint: Path) -> Any:
    """The restored experiment (BenchMARL's ``Experiment.reload_from_file``)."""
    try:
        from benchmarl.experiment import Experiment
        from benchmarl.models.common import Model
    except ImportError as exc:
        raise ImportError(INSTALL) from exc
    scratch = Path(tempfile.mkdtemp(prefix="benchmarl_policy_"))  # BenchMARL writes there
    experiment = Experiment.reload_from_file(
        str(on_the_host(checkpoint, scratch)),
        experiment_patch={**PATCH, "save_folder": str(scratch)},
    )
    policy = experiment.policy
    if any(isinstance(m, Model) and m.centralised for m in policy.modules()):
        raise ValueError(
            f"{checkpoint}: its actor is centralised (it reads every robot's observation); "
            "a robot's policy decides from its own"
        )
    return policy.eval()


def on_the_host(checkpoint: Path, scratch: Path) -> Path:
    """``checkpoint`` as BenchMARL restores it on the host: for a task that stepped its env
    copies on a GPU (``backend: cuda``), a link to it beside a copy of its config.pkl
    whose task steps them on the CPU (the same policy; BenchMARL's patch reaches the
    experiment's config only)."""
    with open(Path(checkpoint).parents[1] / "config.pkl", "rb") as fh:
        pickled = []
        while True:
            try:
                pickled.append(pickle.load(fh))
            except EOFError:
                break
    if pickled[1].get("backend", "cpu") == "cpu":  # the task config
        return checkpoint
    pickled[1] = {**pickled[1], "backend": "cpu"}
    folder = scratch / "restored"
    (folder / "checkpoints").mkdir(parents=True)
    with open(folder / "config.pkl", "wb") as fh:
        for item in pickled:
            pickle.dump(item, fh)
    link = folder / "checkpoints" / Path(checkpoint).name
    link.symlink_to(Path(checkpoint).resolve())
    return link


class BenchMARLPolicy(LoadedPolicy):
    """A BenchMARL checkpoint's policy acting for one robot (module docstring)."""

    SAVED = "checkpoints"
    KIND = "BenchMARL checkpoint"

    def __init__(self, spec: AgentSpec, path: Path) -> None:
        """``path``: a checkpoint, or a folder that holds one (``find``)."""
        saved = self.find(path)
        run = load_once(read_config, saved)
        self.policy = load_once(load_policy, saved)
        super().__init__(spec, *options_record(dict(run.task_config.get("options") or {})))
        self.run = run

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return path.is_file() and CHECKPOINT.fullmatch(path.name) is not None

    @classmethod
    def find(cls, path: Path | str) -> Path:
        """A checkpoint itself; else the latest in ``path/checkpoints`` (an experiment folder,
        a run folder of ``baselines.train``) or, where ``path`` has none of its own, in its
        one experiment folder's (a Hydra run folder)."""
        path = Path(path)
        if cls.accepts(path):
            return path

        def holding(folders: list[Path]) -> list[Path]:
            return [f for f in folders if f.is_dir() and any(map(cls.accepts, f.iterdir()))]

        # a folder's own checkpoints first: a training run folder also holds BenchMARL's
        # experiment folder (the checkpoints a resume reads), best/ and the eval snapshot
        found = holding([path / cls.SAVED]) or holding(sorted(path.glob(f"*/{cls.SAVED}")))
        if len(found) > 1:
            raise ValueError(f"{path} holds several BenchMARL experiments: name one of {found}")
        if not found:
            raise ValueError(
                f"no {cls.KIND} at {path} (expected checkpoint_<frames>.pt, or a folder with "
                f"{cls.SAVED}/)"
            )
        return max((p for p in found[0].iterdir() if cls.accepts(p)), key=_frames)

    @classmethod
    def training_run(cls, saved: Path) -> TrainingRun:
        """What trained ``saved`` (``baselines.evaluation.marl_eval`` names its runs so)."""
        return load_once(read_config, cls.find(saved))

    def decide(self, x: np.ndarray) -> np.ndarray:
        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        n = self.spec.n_agents if self.spec is not None else 1
        index = self.spec.index if self.spec is not None else 0
        # every row this robot's observation: a shared or per-agent decentralised actor
        # gives row ``index`` from row ``index`` alone (its weights when not shared)
        obs = torch.as_tensor(np.asarray(x, np.float32)).expand(n, -1)
        td = TensorDict({GROUP: TensorDict({"observation": obs}, [n])}, [])
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            action = self.policy(td).get((GROUP, "action"))
        return action[index].numpy()
