"""An RLlib checkpoint as a per-agent policy: ``--policy rllib:PATH`` in the evaluator.

PATH is a run folder of ``baselines.train --engine rllib`` (its final ``checkpoint/``),
one of its checkpoints, or any RLlib algorithm checkpoint with one module (or a module
named ``shared``). Only the ``RLModule`` is restored, with torch, in this process: no Ray
runtime starts, so RLlib policies run in the evaluator's worker processes like every
other policy. The policy acts deterministically: the mean of the Gaussian, clipped to
[-1, 1], as RLlib's ``clip_actions`` does for the environment during training.

The run's ``config.json`` (next to the checkpoint) records the environment options it
trained with (``env_options``); a run with the priors (``action_mode``,
``observation_mode``) gets them applied here, as ``SB3Policy`` does, so the policy acts
through the plain interface.

May import: numpy, torch, ray.rllib (inside functions), ``uvms_env.policy``,
``baselines.rl.policy`` (the priors of a run) and ``baselines.distributed.ray_backend``.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from baselines.rl.policy import RobotInputs, comm_from_options, priors_from_options
from uvms_env.policy import AgentSpec

POLICY_ID = "shared"
MODULE_DIR = ("learner_group", "learner", "rl_module")


def resolve_checkpoint(path: str | None) -> Path:
    """The algorithm checkpoint folder of ``rllib:PATH``."""
    if not path:
        raise ValueError("rllib:PATH needs a run folder or a checkpoint folder")
    folder = Path(path)
    if (folder / "checkpoint").is_dir() and not (folder / MODULE_DIR[0]).is_dir():
        folder = folder / "checkpoint"
    if not folder.joinpath(*MODULE_DIR).is_dir():
        raise ValueError(f"no RLlib checkpoint at {path} (expected {'/'.join(MODULE_DIR)})")
    return folder


def module_dir(checkpoint: Path) -> Path:
    modules = checkpoint.joinpath(*MODULE_DIR)
    if (modules / POLICY_ID).is_dir():
        return modules / POLICY_ID
    found = sorted(p for p in modules.iterdir() if p.is_dir())
    if len(found) != 1:
        names = [p.name for p in found]
        raise ValueError(f"{modules} holds modules {names}; expected {POLICY_ID!r} or one")
    return found[0]


def run_config(checkpoint: Path) -> dict[str, Any]:
    """The training run's config.json, if the checkpoint sits in a run folder."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        path = folder / "config.json"
        if path.exists():
            return json.loads(path.read_text())
    return {}


def _load(folder: Path) -> Any:
    """The module, cached until its files change (a training run re-saves its evaluation
    snapshot into the same folder)."""
    stamp = max((p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()), default=0)
    return _load_cached(str(folder.resolve()), stamp)


@lru_cache(maxsize=8)
def _load_cached(folder: str, stamp: int) -> Any:
    del stamp  # part of the cache key only
    import torch

    from baselines.distributed.ray_backend import require_ray

    require_ray()
    from ray.rllib.core.rl_module.rl_module import RLModule

    torch.set_num_threads(1)  # one episode per process; two threads collapse when shared
    module = RLModule.from_checkpoint(folder)
    module.eval()
    return module


class RLlibPolicy:
    """The shared module acting for one robot (see module docstring)."""

    def __init__(self, spec: AgentSpec, path: str | None) -> None:
        self.spec = spec
        checkpoint = resolve_checkpoint(path)
        self.module = _load(module_dir(checkpoint))
        self.env_options: dict[str, Any] = run_config(checkpoint).get("env_options", {})
        self.priors = priors_from_options(self.env_options)
        self.comm = comm_from_options(self.env_options)
        self.reads_messages = self.comm is not None  # it sees the inbox, it may send
        self._io = RobotInputs(self.priors, spec, self.comm)
        self._dist = self.module.get_inference_action_dist_cls()
        self.stats: dict[str, Any] = {}

    def reset(self) -> None:
        self._io.reset()

    def executed(self, action: np.ndarray) -> None:
        self._io.executed(action)

    def act(self, obs: np.ndarray) -> np.ndarray:
        import torch

        raw, x = self._io.inputs(obs)
        x = torch.as_tensor(np.asarray(x, np.float32)[None])
        with torch.no_grad():
            out = self.module.forward_inference({"obs": x})
            action = self._dist.from_logits(out["action_dist_inputs"]).to_deterministic().sample()
        return self._io.action(raw, np.clip(action[0].numpy(), -1.0, 1.0))


def factory(path: str | None):
    """``rllib:PATH`` for ``baselines.policies``: load once, then one policy per agent."""
    resolve_checkpoint(path)  # fail before the episode starts
    return lambda spec: RLlibPolicy(spec, path)
