"""stable-baselines3's ``VecEnv`` over a ``VectorEnv``: one policy shared by every robot.

    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv
    venv = VectorVecEnv(VectorEnv("short", num_envs=64, dtype="float32"), seed=0)

The K environments of N robots are K N sub-environments, ordered environment-major then
by robot (environment 0's uvms_0, uvms_1, ..., environment 1's uvms_0, ...): each
sub-environment is one robot acting from its own observation with the team reward, and a
team's sub-environments end their episode together. The step is the ``VectorEnv``'s,
reshaped; Python builds one small info dict per sub-environment (SB3 wants a list) and
nothing else per robot.

May import: numpy, gymnasium, stable-baselines3, ``uvms_env.env.infos`` (the end codes) and
``uvms_env.vector.env``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from uvms_env.env.infos import end_code
from uvms_env.vector.env import VectorEnv

# ConcatVecEnv: part j's seed is the given one plus j times this (a prime: the parts'
# episode seeds do not line up)
PART_SEED_STRIDE = 7919
# Attributes SB3 asks every sub-environment for that a VectorEnv does not define.
_ATTRIBUTE_DEFAULTS: dict[str, Any] = {"render_mode": None}


class VectorVecEnv(VecEnv):
    """``VecEnv`` of ``K N`` robot sub-environments stepping one ``VectorEnv``.

    | SB3 | here |
    |---|---|
    | observations | (K N, 79) float32 |
    | actions | (K N, 8), clipped by SB3 to [-1, 1] |
    | rewards | (K N,) float32: the team reward repeated for each robot |
    | dones | (K N,): the team's episode ended (terminated or truncated) |
    | infos | one dict per sub-environment: the robot's ``cost`` |

    Where the episode ended, the infos also hold ``terminal_observation`` (the robot's last
    observation), ``TimeLimit.truncated`` and, as the single env's last infos name them
    (``uvms_env.env.infos``), ``episode_end`` (the end's code), ``diverged`` and the
    episode's metrics, and its time limit ``max_cycles``.

    The single env's per-step ``constraint_<kind>`` and ``reward_<term>`` keys are left out
    (K N dicts of them a step would cost more than the step): the last step's batched
    infos (arrays over environments) are in ``last_infos``.

    **Seeding** (the adapters' one rule, ``uvms_env.vector.seeding``): the first
    ``reset()`` is the ``VectorEnv``'s ``reset(seed=seed)`` (with ``seed=None``: its own
    first seed); after ``seed(s)`` the next ``reset()`` is ``reset(seed=s)``, the episodes
    then seeded by that rule. Any other ``reset()`` continues every environment's sequence.

    ``get_attr``, ``set_attr`` and ``env_method`` act on the one ``VectorEnv`` behind
    every sub-environment (``env_method`` calls the method once and repeats its result
    for each index asked for); nothing is wrapped (``env_is_wrapped``: all False).
    """

    def __init__(self, vector_env: VectorEnv, seed: int | None = None) -> None:
        self.vector_env = vector_env
        self.n_agents = vector_env.n
        self.agents = list(vector_env.possible_agents)
        # each team's first robot: one sub-environment per team episode (records, callbacks)
        self.team_leaders = np.tile(np.arange(vector_env.n) == 0, vector_env.num_envs)
        super().__init__(
            vector_env.num_envs * vector_env.n,
            vector_env.single_observation_space,
            vector_env.single_action_space,
        )
        self._next_seed = seed
        self._actions: np.ndarray | None = None
        self.last_infos: dict[str, Any] = {}

    # -- SB3's VecEnv -------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        obs, infos = self.vector_env.reset(seed=self._next_seed)
        self._next_seed = None
        self._reset_seeds()
        self._reset_options()
        seeds = np.repeat(np.asarray(infos["episode_seed"]), self.n_agents).tolist()
        self.reset_infos = [{"episode_seed": s} for s in seeds]
        self._actions = None
        return obs.reshape(self.num_envs, -1)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait called without step_async")
        venv, n = self.vector_env, self.n_agents
        try:
            actions = self._actions.reshape(venv.num_envs, n, -1)
        except ValueError:
            raise ValueError(
                f"actions must have shape ({self.num_envs}, {venv.single_action_space.shape[0]}), "
                f"got {self._actions.shape}"
            ) from None
        self._actions = None
        obs, reward, terminated, truncated, infos = venv.step(actions)
        self.last_infos = infos
        ended = terminated | truncated
        rewards = np.repeat(reward.astype(np.float32), n)
        dones = np.repeat(ended, n)
        out = [{"cost": c} for c in infos["cost"].reshape(-1).tolist()]
        if ended.any():
            final = infos["final_observation"]
            for k in np.flatnonzero(ended).tolist():
                shared = {
                    "TimeLimit.truncated": bool(truncated[k] and not terminated[k]),
                    "episode_end": end_code(infos["episode_end"][k]),
                    "diverged": int(bool(infos["diverged_reason"][k])),
                    "max_cycles": int(venv.max_cycles),
                    **infos["metrics"][k],
                }
                for a in range(n):
                    info = out[k * n + a]
                    info.update(shared)
                    info["terminal_observation"] = final[k, a].copy()
        return obs.reshape(self.num_envs, -1), rewards, dones, out

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The next ``reset()`` starts environment k with seed ``seed + k`` (``None``: keep
        the pending seed). Returns each sub-environment's pending seed (None: none)."""
        if seed is not None:
            self._next_seed = int(seed)
        if self._next_seed is None:
            return [None] * self.num_envs
        return [self._next_seed + k for k in range(self.vector_env.num_envs) for _ in self.agents]

    def close(self) -> None:
        self.vector_env.close()

    # -- attributes and methods: the VectorEnv's ------------------------------------------
    def _count(self, indices: VecEnvIndices) -> int:
        return len(list(self._get_indices(indices)))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        if attr_name in _ATTRIBUTE_DEFAULTS:
            value = getattr(self.vector_env, attr_name, _ATTRIBUTE_DEFAULTS[attr_name])
        else:
            value = getattr(self.vector_env, attr_name)
        return [value] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.vector_env, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        result = getattr(self.vector_env, method_name)(*method_args, **method_kwargs)
        return [result] * self._count(indices)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * self._count(indices)


class ConcatVecEnv(VecEnv):
    """Several ``VecEnv`` of robot sub-environments side by side as one: e.g. one
    ``VectorVecEnv`` per team size, so that one policy learns from teams of every size at
    once (the observation of a robot does not depend on N). Sub-environment i of part j
    is number ``offset_j + i``; ``team_leaders`` concatenates the parts' (each team's
    first robot). The parts share the observation and action spaces (checked) and step
    one after another in this process.

    ``get_attr``, ``set_attr`` and ``env_method`` go to the part that holds each index."""

    def __init__(self, parts: Sequence[VecEnv]) -> None:
        parts = list(parts)
        if not parts:
            raise ValueError("ConcatVecEnv needs at least one part")
        first = parts[0]
        for j, part in enumerate(parts[1:], 1):
            if part.observation_space != first.observation_space:
                raise ValueError(
                    f"part {j}'s observation space {part.observation_space} differs from "
                    f"part 0's {first.observation_space}"
                )
            if part.action_space != first.action_space:
                raise ValueError(
                    f"part {j}'s action space {part.action_space} differs from part 0's "
                    f"{first.action_space}"
                )
        self.parts = parts
        sizes = [p.num_envs for p in parts]
        self._bounds = np.concatenate([[0], np.cumsum(sizes)])
        self.team_leaders = np.concatenate(
            [np.asarray(getattr(p, "team_leaders", np.ones(p.num_envs, bool))) for p in parts]
        )
        super().__init__(int(sum(sizes)), first.observation_space, first.action_space)

    @property
    def last_infos(self) -> dict[str, np.ndarray]:
        """The parts' last batched infos that are per robot, in sub-environment order:
        ``constraint_values`` (robots, C) and ``cost`` (robots,) (what the parts' other
        infos hold per environment copy has no common shape)."""
        infos = [p.last_infos for p in self.parts]  # type: ignore[attr-defined]
        width = infos[0]["constraint_values"].shape[-1]
        return {
            "constraint_values": np.concatenate(
                [np.asarray(i["constraint_values"]).reshape(-1, width) for i in infos]
            ),
            "cost": np.concatenate([np.asarray(i["cost"]).reshape(-1) for i in infos]),
        }

    def _slices(self) -> list[slice]:
        return [slice(a, b) for a, b in zip(self._bounds[:-1], self._bounds[1:], strict=True)]

    def reset(self) -> np.ndarray:
        out = [p.reset() for p in self.parts]
        self.reset_infos = [info for p in self.parts for info in p.reset_infos]
        return np.concatenate(out)

    def step_async(self, actions: np.ndarray) -> None:
        for p, sl in zip(self.parts, self._slices(), strict=True):
            p.step_async(actions[sl])

    def step_wait(self) -> VecEnvStepReturn:
        results = [p.step_wait() for p in self.parts]
        obs = np.concatenate([r[0] for r in results])
        rewards = np.concatenate([r[1] for r in results])
        dones = np.concatenate([r[2] for r in results])
        infos = [info for r in results for info in r[3]]
        return obs, rewards, dones, infos

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Part j is seeded ``seed + j * PART_SEED_STRIDE`` (None: keep its pending seed)."""
        out: list[int | None] = []
        for j, p in enumerate(self.parts):
            out += list(p.seed(None if seed is None else seed + j * PART_SEED_STRIDE))
        return out

    def close(self) -> None:
        for p in self.parts:
            p.close()

    def _located(self, indices: VecEnvIndices) -> list[tuple[VecEnv, list[int]]]:
        """(part, its local indices) for each part that holds some of ``indices``."""
        wanted = list(self._get_indices(indices))
        out = []
        for p, part in zip(self.parts, self._slices(), strict=True):
            local = [int(i - part.start) for i in wanted if part.start <= i < part.stop]
            if local:
                out.append((p, local))
        return out

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [v for p, local in self._located(indices) for v in p.get_attr(attr_name, local)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for p, local in self._located(indices):
            p.set_attr(attr_name, value, local)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        return [
            v
            for p, local in self._located(indices)
            for v in p.env_method(method_name, *method_args, indices=local, **method_kwargs)
        ]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [
            v for p, local in self._located(indices) for v in p.env_is_wrapped(wrapper_class, local)
        ]
