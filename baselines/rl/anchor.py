"""Anchored fine-tuning of a clone (``--anchor W`` with ``--init-actor``): each robot's
reward loses W |s a - r_c(x)|^2 / 8, the squared distance between the input the PPO
action asks for and the clone's, both as residuals around a_ss (s the residual scale, a
the action in [-1, 1], r_c the clone's residual on the robot's observation x, clipped to
the action's reach).

Why: PPO started from a DAgger clone drifted away from it within a few hundred thousand
robot-steps on this task and lost what the clone could do (docs/notes/2026-11-26-learned-
baselines-on-the-distribution.md): its advantages are noisy where success and violations
are rare events. Penalizing the distance to a reference policy in the reward is the
KL-regularized objective of RL from a prior (for Gaussian policies of one spread, the KL
to the reference is this squared distance of the means, up to a factor): the policy
leaves the clone only where the task reward (and the constraint cost) pays for it.

The wrapper sits on the raw robot sub-environments (below ``VecNormalize``), reads the
observation each action answered and evaluates the clone's network on all of them in
one torch call; ``infos[i]["anchor_penalty"]`` holds the step's penalty.

May import: numpy, torch, stable-baselines3 and ``baselines.networks`` (the clone's network).
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from baselines.networks.features import ACT_DIM
from baselines.networks.mlp import MLPPolicyNet


class AnchorPenalty(VecEnvWrapper):
    """Subtracts ``weight * mean((s a - clip(r_c(x), -s, s))^2)`` from each robot
    sub-environment's reward (module docstring); ``net`` is the clone (a residual network
    on the environment's own observation), ``residual_scale`` the environment's s."""

    def __init__(
        self, venv: VecEnv, net: MLPPolicyNet, residual_scale: float, weight: float
    ) -> None:
        if not net.residual:
            raise ValueError("the anchor is a clone on residual inputs (features or memory)")
        if not (np.isfinite(weight) and weight >= 0):
            raise ValueError(f"the anchor's weight must be >= 0, got {weight}")
        size = venv.observation_space.shape[0]
        if net.obs_mean.numel() != size:
            raise ValueError(
                f"the clone reads {net.obs_mean.numel()} numbers, the environment gives {size}"
            )
        super().__init__(venv)
        self.net, self.scale, self.weight = net, float(residual_scale), float(weight)
        self._obs: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)
        self.venv.step_async(actions)

    def clone_residual(self, obs: np.ndarray) -> np.ndarray:
        """r_c(x) (robots, 8): the clone's output minus its a_ss input."""
        with torch.no_grad():
            x = torch.as_tensor(np.asarray(obs, np.float32))
            return (self.net(x) - x[..., -ACT_DIM:]).numpy()

    def step_wait(self) -> VecEnvStepReturn:
        assert self._obs is not None and self._actions is not None, "step before reset"
        answered, actions = self._obs, self._actions
        obs, reward, done, infos = self.venv.step_wait()
        s = self.scale
        target = np.clip(self.clone_residual(answered), -s, s)
        asked = s * np.clip(actions[:, :ACT_DIM], -1.0, 1.0)
        penalty = self.weight * np.mean((asked - target) ** 2, axis=1)
        for info, p in zip(infos, penalty.tolist(), strict=True):
            info["anchor_penalty"] = p
        self._obs = obs
        return obs, (reward - penalty).astype(np.float32), done, infos
