"""TorchRL's ``EnvBase`` over a ``VectorEnv``: K environments as one batched TorchRL env, the
robots in one agent group as TorchRL's PettingZoo wrapper lays out a parallel env.

    from uvms_env.vector import VectorEnv
    from uvms_env.vector.torchrl_env import CoopTransportTorchRLEnv
    env = CoopTransportTorchRLEnv(VectorEnv("short", num_envs=64, dtype="float32"))
    td = env.rollout(100)   # td["next", "uvms", "reward"]: (64, 100, N, 1)

Layout (batch size (K,)): group ``"uvms"`` (the agents ``uvms_0 ... uvms_{N-1}``, the
name prefix TorchRL's PettingZoo wrapper groups them by) with ``observation`` (K, N, 79)
float32, ``action`` (K, N, 8) in [-1, 1], ``reward`` (K, N, 1) (the team reward for every
robot), ``done``/``terminated``/``truncated`` (K, N, 1); the team's ``done``,
``terminated``, ``truncated`` (K, 1) at the root. ``state`` (K, 20 N + 19) is the global
state, for centralized critics only (of the episode under way: after an automatic reset,
the new one's).

Resets. TorchRL resets an ended environment on the step after it ended (the ``_reset``
mask); the ``VectorEnv`` has already started its next episode inside ``step`` (same-step
automatic reset). So ``step`` returns the ended episode's last observation as
``next.observation`` and keeps the new episode's first one, which the reset then hands
over; a ``_reset`` of an environment that did not end starts its next episode where it
stands (``VectorEnv.restart``). ``set_seed(s)``: the next full reset is
``reset(seed=s)`` (environment k: seed ``s + k``).

Backends. Over the CPU backend the numpy arrays become torch tensors on ``device``
(default the host). Over the CUDA backend (``VectorEnv(..., backend="cuda", device=D)``)
the env's device is the vector env's (``cuda:D``, or the host for the emulated
``device="cpu"``) and its tensors go in and out as they are: actions are handed to
``step`` as tensors, observations, rewards, flags and states stay where the step left
them, and the end-of-episode bookkeeping is tensor arithmetic, so that a rollout never
passes through numpy. The host reads a mask only where ``_reset`` restarts environments
that had not ended (the ids ``VectorEnv.restart`` takes).

Only imported on demand (TorchRL is optional). May import: numpy, torch, tensordict,
torchrl and ``uvms_env.vector.env``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from uvms_env.vector.env import VectorEnv

GROUP = "uvms"


class CoopTransportTorchRLEnv(EnvBase):
    """``EnvBase`` of batch size (K,) stepping one ``VectorEnv`` (see module docstring).

    ``device``: where the tensors live; default the vector env's (the host for the CPU
    backend)."""

    def __init__(self, vector_env: VectorEnv, device: str | torch.device | None = None) -> None:
        k, n = vector_env.num_envs, vector_env.n
        self._native = vector_device(vector_env)
        super().__init__(
            device=self._native if device is None else device, batch_size=torch.Size([k])
        )
        self.vector_env = vector_env
        self._torch_backend = vector_env.backend != "cpu"
        self.group_map = {GROUP: list(vector_env.possible_agents)}
        obs_space = vector_env.single_observation_space
        size = obs_space.shape[0]
        low = torch.as_tensor(np.broadcast_to(obs_space.low, (k, n, size)).copy())
        high = torch.as_tensor(np.broadcast_to(obs_space.high, (k, n, size)).copy())
        state_size = vector_env.state().shape[1]
        act_size = vector_env.single_action_space.shape[0]  # 8, or more with a channel
        self.observation_spec = Composite(
            {
                GROUP: Composite(
                    {"observation": Bounded(low, high, (k, n, size), self.device)},
                    shape=(k, n),
                ),
                "state": Unbounded((k, state_size), self.device, torch.float32),
            },
            shape=(k,),
        )
        self.action_spec = Composite(
            {
                GROUP: Composite(
                    {"action": Bounded(-1.0, 1.0, (k, n, act_size), self.device, torch.float32)},
                    shape=(k, n),
                )
            },
            shape=(k,),
        )
        self.reward_spec = Composite(
            {GROUP: Composite({"reward": Unbounded((k, n, 1), self.device)}, shape=(k, n))},
            shape=(k,),
        )
        flags = ("done", "terminated", "truncated")
        team = {f: Categorical(2, (k, 1), self.device, torch.bool) for f in flags}
        robots = {f: Categorical(2, (k, n, 1), self.device, torch.bool) for f in flags}
        self.done_spec = Composite({**team, GROUP: Composite(robots, shape=(k, n))}, shape=(k,))
        self._next_seed: int | None = None
        # each env's episode under way (None: not reset); replaced, never written in place
        # once handed out, so the tensors of earlier outputs keep their values
        self._obs: torch.Tensor | None = None
        # envs whose episode ended: already restarted inside VectorEnv.step
        self._ended = torch.zeros(k, dtype=torch.bool, device=self.device)

    # -- EnvBase ----------------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        venv = self.vector_env
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None or self._obs is None or bool(mask.all()):
            obs, _ = venv.reset(seed=self._next_seed)
            self._obs = self._tensor(obs)
            self._next_seed = None
            self._ended.zero_()
        else:
            mask = mask.reshape(-1).to(self.device)
            going_on = torch.nonzero(mask & ~self._ended).reshape(-1)
            if len(going_on):
                self._obs = self._obs.clone()
                self._obs[going_on] = self._tensor(venv.restart(going_on.tolist()))
            self._ended &= ~mask
        none = torch.zeros(venv.num_envs, dtype=torch.bool, device=self.device)
        return self._output(self._obs, None, none, none)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get((GROUP, "action")).detach()
        if self._torch_backend:
            step_input: Any = action.to(self._native)
        else:
            step_input = action.cpu().numpy()
        obs, reward, terminated, truncated, infos = self.vector_env.step(step_input)
        self._obs = self._tensor(obs)  # the next episodes' starts where one ended
        terminated, truncated = self._tensor(terminated), self._tensor(truncated)
        ended = terminated | truncated
        self._ended |= ended
        # where an episode ended, the step's observation is the ended episode's last one
        final = self._tensor(infos["final_observation"])
        last = torch.where(ended.reshape(-1, 1, 1), final, self._obs)
        return self._output(last, self._tensor(reward), terminated, truncated)

    def _set_seed(self, seed: int | None) -> int | None:
        self._next_seed = seed
        return None if seed is None else seed + self.vector_env.num_envs

    # -- internals --------------------------------------------------------------------------
    def _tensor(self, x: Any) -> torch.Tensor:
        """A step result on this env's device: torch tensors as they are (moved only if this
        env was given another device), numpy arrays of the CPU backend as tensors."""
        if isinstance(x, torch.Tensor):
            return x.to(self.device)
        return torch.as_tensor(x, device=self.device)

    def _output(
        self,
        obs: torch.Tensor,
        reward: torch.Tensor | None,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
    ) -> TensorDict:
        k, n = self.vector_env.num_envs, self.vector_env.n
        dev = self.device

        def robots(x: torch.Tensor) -> torch.Tensor:
            # contiguous: an expanded view would refuse the in-place writes of consumers
            return x.reshape(k, 1, 1).expand(k, n, 1).contiguous()

        done = terminated | truncated
        group: dict[str, torch.Tensor] = {
            "observation": obs,
            "done": robots(done),
            "terminated": robots(terminated),
            "truncated": robots(truncated),
        }
        if reward is not None:
            group["reward"] = robots(reward.to(torch.float32))
        return TensorDict(
            {
                GROUP: TensorDict(group, batch_size=(k, n), device=dev),
                "state": self._tensor(self.vector_env.state()),
                "done": done.reshape(k, 1),
                "terminated": terminated.reshape(k, 1),
                "truncated": truncated.reshape(k, 1),
            },
            batch_size=(k,),
            device=dev,
        )


def vector_device(vector_env: VectorEnv) -> torch.device:
    """Where ``vector_env``'s tensors live: the host for the CPU backend and the emulated
    CUDA backend (``device="cpu"``), else its GPU."""
    if vector_env.backend == "cpu" or vector_env.device == "cpu":
        return torch.device("cpu")
    return torch.device("cuda", int(vector_env.device))
