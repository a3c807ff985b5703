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
    """``EnvBase`` of batch size (K,) stepping one ``VectorEnv`` (see module docstring)."""

    def __init__(self, vector_env: VectorEnv, device: str | torch.device = "cpu") -> None:
        k, n = vector_env.num_envs, vector_env.n
        super().__init__(device=device, batch_size=torch.Size([k]))
        self.vector_env = vector_env
        self.group_map = {GROUP: list(vector_env.possible_agents)}
        obs_space = vector_env.single_observation_space
        low = torch.as_tensor(np.broadcast_to(obs_space.low, (k, n, obs_space.shape[0])).copy())
        high = torch.as_tensor(np.broadcast_to(obs_space.high, (k, n, obs_space.shape[0])).copy())
        state_size = vector_env.state().shape[1]
        self.observation_spec = Composite(
            {
                GROUP: Composite(
                    {"observation": Bounded(low, high, (k, n, obs_space.shape[0]), self.device)},
                    shape=(k, n),
                ),
                "state": Unbounded((k, state_size), self.device, torch.float32),
            },
            shape=(k,),
        )
        self.action_spec = Composite(
            {
                GROUP: Composite(
                    {"action": Bounded(-1.0, 1.0, (k, n, 8), self.device, torch.float32)},
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
        self._obs: np.ndarray | None = None  # each env's episode under way (None: not reset)
        self._ended: set[int] = set()  # envs whose episode ended: already restarted inside

    # -- EnvBase ----------------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        venv = self.vector_env
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None or bool(mask.all()) or self._obs is None:
            self._obs, _ = venv.reset(seed=self._next_seed)
            self._next_seed = None
            self._ended.clear()
        else:
            ids = torch.nonzero(mask.reshape(-1)).reshape(-1).tolist()
            going_on = [i for i in ids if i not in self._ended]  # ended ones already restarted
            if going_on:
                self._obs[going_on] = venv.restart(going_on)
            self._ended.difference_update(ids)
        k = venv.num_envs
        return self._output(self._obs, None, np.zeros(k, bool), np.zeros(k, bool))

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get((GROUP, "action")).detach().cpu().numpy()
        obs, reward, terminated, truncated, infos = self.vector_env.step(action)
        self._obs = obs  # the next episodes' starts where one ended
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):
            self._ended.update(ended.tolist())
            obs = obs.copy()
            obs[ended] = infos["final_observation"][ended]
        return self._output(obs, reward, terminated, truncated)

    def _set_seed(self, seed: int | None) -> int | None:
        self._next_seed = seed
        return None if seed is None else seed + self.vector_env.num_envs

    # -- internals --------------------------------------------------------------------------
    def _output(
        self,
        obs: np.ndarray,
        reward: np.ndarray | None,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> TensorDict:
        k, n = self.vector_env.num_envs, self.vector_env.n
        dev = self.device

        def flag(x: np.ndarray, shape: tuple[int, ...]) -> torch.Tensor:
            return torch.as_tensor(
                np.broadcast_to(x.reshape(k, *([1] * (len(shape) - 1))), shape).copy(), device=dev
            )

        done = terminated | truncated
        group: dict[str, torch.Tensor] = {
            "observation": torch.tensor(obs, device=dev),  # a copy: _obs changes in place
            "done": flag(done, (k, n, 1)),
            "terminated": flag(terminated, (k, n, 1)),
            "truncated": flag(truncated, (k, n, 1)),
        }
        if reward is not None:
            group["reward"] = flag(reward.astype(np.float32), (k, n, 1))
        return TensorDict(
            {
                GROUP: TensorDict(group, batch_size=(k, n), device=dev),
                "state": torch.as_tensor(self.vector_env.state(), device=dev),
                "done": flag(done, (k, 1)),
                "terminated": flag(terminated, (k, 1)),
                "truncated": flag(truncated, (k, 1)),
            },
            batch_size=(k,),
            device=dev,
        )
