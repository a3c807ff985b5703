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
``reset(seed=s)`` (environment k: seed ``s + k``); with ``fixed_seed=True`` every reset
without a ``_reset`` entry (each ``rollout``, a collector's first reset) is, so that
evaluations that start afresh play the same episodes.

Infos (``info=True``): ``(uvms, info)`` holds, per robot (K, N) float32, each step's
``cost`` (its violated safety constraints this period) and ``constraint_<kind>`` (its
constraint values, g <= 0 holds) and, on the step that ends an episode (zero on every
other), ``episode_end`` (how it ended: the code of ``uvms_env.env.infos.EPISODE_END_NAMES``),
that episode's metrics (``uvms_env.task.metrics``: success, clean success with and without
the tolerance, the return, the violation periods and the graded safety per kind, ...;
``internal_wrench_rms`` when the vector env computes it) and ``episode_cost`` (the robot's
``cost`` summed over the episode). They have the names of the single env's infos, which
TorchRL's ``PettingZooWrapper`` carries as they are (``uvms_env.env.infos``).

Rendering: ``render(env_index=0)`` draws one copy's current state as
``parallel_env(render_mode="rgb_array").render()`` does (``uvms_env.env.render``, imported
by the first call only: the step never draws).

Backends. Over the CPU backend the numpy arrays become torch tensors on ``device``
(default the host). Over the CUDA backend (``VectorEnv(..., backend="cuda", device=D)``)
the env's device is the vector env's (``cuda:D``, or the host for the emulated
``device="cpu"``) and its tensors go in and out as they are: actions are handed to
``step`` as tensors, observations, rewards, flags and states stay where the step left
them, and the end-of-episode bookkeeping is tensor arithmetic, so that a rollout never
passes through numpy. The host reads a mask only where ``_reset`` restarts environments
that had not ended (the ids ``VectorEnv.restart`` takes).

Only imported on demand (TorchRL is optional). May import: numpy, torch, tensordict,
torchrl, ``uvms_env.vector.env``, ``uvms_env.task.metrics``, ``uvms_env.env`` (options; the
renderer only inside ``render``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from uvms_env.env.infos import CONSTRAINT_PREFIX, end_code
from uvms_env.env.options import state_structure
from uvms_env.task.metrics import metric_keys
from uvms_env.vector.env import VectorEnv

GROUP = "uvms"


def step_info_keys(constraints: Sequence[str]) -> tuple[str, ...]:
    """The names of the values every step fills: the robot's cost and its constraint values."""
    return ("cost", *(CONSTRAINT_PREFIX + kind for kind in constraints))


def episode_info_keys(constraints: Sequence[str], internal_wrench: bool) -> tuple[str, ...]:
    """The names of an ended episode's values in the infos, in order: how it ended, the
    metrics (``uvms_env.task.metrics.metric_keys``; ``internal_wrench_rms`` only where the
    vector env computes it) and the robot's summed cost."""
    keys = [k for k in metric_keys(constraints) if internal_wrench or k != "internal_wrench_rms"]
    return ("episode_end", *keys, "episode_cost")


def episode_info_values(
    metrics: Mapping[str, Any], episode_cost: float, keys: Sequence[str], end: str = ""
) -> list[float]:
    """``keys``' values of one ended episode: its metrics dict, the robot's summed cost and
    ``end``, the name of how it ended (a metric the episode has none of is NaN)."""
    special = {"episode_cost": episode_cost, "episode_end": end_code(end) if end else 0}
    return [float(special[key] if key in special else metrics[key]) for key in keys]


class CoopTransportTorchRLEnv(EnvBase):
    """``EnvBase`` of batch size (K,) stepping one ``VectorEnv`` (see module docstring).

    ``device``: where the tensors live; default the vector env's (the host for the CPU
    backend). ``info``: carry the infos under ``(uvms, info)``; ``fixed_seed``: every fresh
    reset starts from the seed of the last ``set_seed`` (module docstring)."""

    def __init__(
        self,
        vector_env: VectorEnv,
        device: str | torch.device | None = None,
        info: bool = False,
        fixed_seed: bool = False,
    ) -> None:
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
        group_obs: dict[str, Any] = {"observation": Bounded(low, high, (k, n, size), self.device)}
        self.episode_keys: tuple[str, ...] = ()
        self.step_keys: tuple[str, ...] = ()
        if info:
            wrench = vector_env.internal_wrench_every > 0
            self.episode_keys = episode_info_keys(vector_env.task.constraints, wrench)
            self.step_keys = step_info_keys(vector_env.task.constraints)
            group_obs["info"] = Composite(
                {
                    key: Unbounded((k, n), self.device, torch.float32)
                    for key in (*self.step_keys, *self.episode_keys)
                },
                shape=(k, n),
            )
        self.observation_spec = Composite(
            {
                GROUP: Composite(group_obs, shape=(k, n)),
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
        self.carry_info, self.fixed_seed = info, fixed_seed
        self._next_seed: int | None = None
        self._seed: int | None = None  # the last set_seed's, for fixed_seed
        self._episode_cost = torch.zeros(k, n, dtype=torch.float64, device=self.device)
        self._renderer: Any = None
        self._path: list[np.ndarray] = []
        self._last_time = math.inf
        self._calls = 0
        self._frame: np.ndarray | None = None
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
            seed = self._next_seed
            if seed is None and mask is None and self.fixed_seed:
                seed = self._seed
            obs, _ = venv.reset(seed=seed)
            self._obs = self._tensor(obs)
            self._next_seed = None
            self._ended.zero_()
            self._episode_cost.zero_()
        else:
            mask = mask.reshape(-1).to(self.device)
            going_on = torch.nonzero(mask & ~self._ended).reshape(-1)
            if len(going_on):
                self._obs = self._obs.clone()
                self._obs[going_on] = self._tensor(venv.restart(going_on.tolist()))
                self._episode_cost[going_on] = 0.0
            self._ended &= ~mask
        none = torch.zeros(venv.num_envs, dtype=torch.bool, device=self.device)
        info = self._neutral_info() if self.carry_info else None
        return self._output(self._obs, None, none, none, info)

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
        info = self._step_info(infos, ended) if self.carry_info else None
        return self._output(last, self._tensor(reward), terminated, truncated, info)

    def _set_seed(self, seed: int | None) -> int | None:
        self._next_seed = self._seed = seed
        return None if seed is None else seed + self.vector_env.num_envs

    # -- rendering --------------------------------------------------------------------------
    def render(self, env_index: int = 0, every: int = 1) -> np.ndarray:
        """(360, 720, 3) uint8 picture of copy ``env_index``'s current state and of its
        object's path since this copy's first rendered step of the episode. ``every``: draw
        on every ``every``-th call of an episode and return the last picture in between
        (drawing costs ~0.1 s; a video of a long episode needs fewer)."""
        from uvms_env.env.render import Renderer  # matplotlib: never on the step's path

        venv = self.vector_env
        scenario = venv.scenarios[env_index]
        state = venv.state()[env_index]
        state = state.cpu().numpy() if isinstance(state, torch.Tensor) else np.asarray(state)
        layout = state_structure(venv.n)
        time = float(state[layout["time_fraction"]][0]) * venv.max_cycles * scenario.period
        x_o = state[layout["object_pose"]].astype(float)
        if self._renderer is None or self._renderer.scenario is not scenario:
            self.close_renderer()
            self._renderer = Renderer(scenario, venv.sim.object.segments)
            self._last_time = math.inf
        if time < self._last_time:  # a new episode
            self._path, self._calls = [], 0
        self._last_time = time
        self._path.append(x_o[:3].copy())
        if self._calls % max(int(every), 1) == 0 or self._frame is None:
            q = state[layout["q"]].astype(float).reshape(venv.n, -1)
            self._frame = self._renderer.frame(q, x_o, np.array(self._path), time)
        self._calls += 1
        return self._frame

    def close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer, self._frame = None, None

    # -- internals --------------------------------------------------------------------------
    def _tensor(self, x: Any) -> torch.Tensor:
        """A step result on this env's device: torch tensors as they are (moved only if this
        env was given another device), numpy arrays of the CPU backend as tensors."""
        if isinstance(x, torch.Tensor):
            return x.to(self.device)
        return torch.as_tensor(x, device=self.device)

    def _neutral_info(self) -> dict[str, torch.Tensor]:
        k, n = self.vector_env.num_envs, self.vector_env.n
        zero = torch.zeros(k, n, dtype=torch.float32, device=self.device)
        return {key: zero.clone() for key in (*self.step_keys, *self.episode_keys)}

    def _step_info(self, infos: dict[str, Any], ended: torch.Tensor) -> dict[str, torch.Tensor]:
        """The step's ``(uvms, info)``: the robots' cost and constraint values, and the ended
        episodes' values."""
        cost = self._tensor(infos["cost"])
        self._episode_cost += cost
        info = self._neutral_info()
        info["cost"] = cost.to(torch.float32)
        g = self._tensor(infos["constraint_values"]).to(torch.float32)  # (K, N, kinds)
        for j, key in enumerate(self.step_keys[1:]):
            info[key] = g[..., j]
        done = torch.nonzero(ended).reshape(-1).tolist()  # the host reads the ended few
        if done:
            ends = infos["episode_end"]
            rows = torch.tensor(
                [
                    [
                        episode_info_values(
                            infos["metrics"][e], float(c), self.episode_keys, str(ends[e])
                        )
                        for c in self._episode_cost[e].tolist()
                    ]
                    for e in done
                ],
                dtype=torch.float32,
                device=self.device,
            )  # (ended, N, keys)
            for j, key in enumerate(self.episode_keys):
                info[key][done] = rows[:, :, j]
            self._episode_cost[done] = 0.0
        return info

    def _output(
        self,
        obs: torch.Tensor,
        reward: torch.Tensor | None,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
        info: dict[str, torch.Tensor] | None = None,
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
        if info is not None:
            group["info"] = TensorDict(info, batch_size=(k, n), device=dev)
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
