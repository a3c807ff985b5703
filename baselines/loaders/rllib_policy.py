"""An RLlib checkpoint as a per-agent policy: ``--policy rllib:PATH`` in the evaluator.

PATH is a run folder of ``baselines.train --library rllib`` (its final ``checkpoint/``),
one of its checkpoints, or any RLlib algorithm checkpoint with one module (or a module
named ``shared``). Only the ``RLModule`` is restored, with torch, in this process: no Ray
runtime starts, so RLlib policies run in the evaluator's worker processes like every
other policy. The policy acts deterministically: the mean of the Gaussian, clipped to
[-1, 1], as RLlib's ``clip_actions`` does for the environment during training. The run's
priors: ``baselines.loaders.saved``.

May import: numpy, torch, ray.rllib (inside functions), ``uvms_env.policy``,
``baselines.loaders.saved`` and ``baselines.ray_runtime`` (the install check).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy, load_once, run_record
from uvms_env.policy import AgentSpec

POLICY_ID = "shared"
MODULE_DIR = ("learner_group", "learner", "rl_module")


def module_dir(checkpoint: Path) -> Path:
    modules = checkpoint.joinpath(*MODULE_DIR)
    if (modules / POLICY_ID).is_dir():
        return modules / POLICY_ID
    found = sorted(p for p in modules.iterdir() if p.is_dir())
    if len(found) != 1:
        names = [p.name for p in found]
        raise ValueError(f"{modules} holds modules {names}; expected {POLICY_ID!r} or one")
    return found[0]


def load_module(folder: Path) -> Any:
    """The ``RLModule`` saved in ``folder``, in evaluation mode."""
    from baselines.ray_runtime import require_ray

    require_ray()
    from ray.rllib.core.rl_module.rl_module import RLModule

    module = RLModule.from_checkpoint(str(folder))
    module.eval()
    return module


class RLlibPolicy(LoadedPolicy):
    """The shared module acting for one robot (see module docstring)."""

    SAVED = "checkpoint"  # the final checkpoint in a run folder
    KIND = "RLlib checkpoint"

    def __init__(self, spec: AgentSpec, path: Path) -> None:
        """``path``: the run folder or a checkpoint folder."""
        checkpoint = self.find(path)
        modules = module_dir(checkpoint)
        self.module = load_once(load_module, modules, (modules,))
        super().__init__(spec, *run_record(checkpoint))
        self._dist = self.module.get_inference_action_dist_cls()

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return path.joinpath(*MODULE_DIR).is_dir()

    def decide(self, x: np.ndarray) -> np.ndarray:
        import torch

        x = torch.as_tensor(np.asarray(x, np.float32)[None])
        with torch.no_grad():
            out = self.module.forward_inference({"obs": x})
            action = self._dist.from_logits(out["action_dist_inputs"]).to_deterministic().sample()
        return action[0].numpy()
