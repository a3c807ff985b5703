"""Gymnasium's vector API over a ``VectorEnv``: the centralized view, K environments at once.

    import gymnasium, uvms_env
    envs = gymnasium.make_vec("uvms_env/CoopTransport-v1", num_envs=64, scenario="short",
                              dtype="float32")       # vectorization_mode: vector_entry_point
    obs, infos = envs.reset(seed=0)                  # obs (64, 79 N)
    obs, rewards, terminations, truncations, infos = envs.step(actions)   # actions (64, 8 N)

Each environment is the single Gymnasium environment (``uvms_env.env.gym_wrapper``): the
robots' observations concatenated, their actions concatenated, the team reward. It is
centralized by construction; ``uvms_env.vector.sb3`` gives the decentralized, shared-policy
view for SB3.

May import: numpy, gymnasium, ``uvms_env.env.infos`` (the single view's info layout),
``uvms_env.task.metrics`` and ``uvms_env.vector.env``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector import VectorEnv as GymVectorEnv
from gymnasium.vector.utils import batch_space

from uvms_env.env.infos import CONSTRAINT_PREFIX, InfoLayout, end_code
from uvms_env.scenarios import Scenario
from uvms_env.task.metrics import metric_keys
from uvms_env.vector.env import VectorEnv


class CoopTransportVectorEnv(GymVectorEnv):
    """``gymnasium.vector.VectorEnv`` of K centralized ``uvms_env/CoopTransport-v1`` envs.

    Construct: ``CoopTransportVectorEnv(num_envs=1, scenario="paper", dtype="float64",
    threads=None, **overrides)``, the arguments of ``uvms_env.vector.VectorEnv`` (the
    overrides of ``parallel_env`` and ``geometry_pool``; ``render_mode`` only None: no
    rendering); ``gymnasium.make_vec`` passes its keyword arguments here. Observation
    ``(K, 79 N)`` float32, action ``(K, 8 N)`` in [-1, 1]: agent i's part of a row is
    ``[79 i, 79 (i + 1))`` and ``[8 i, 8 (i + 1))``, as in the single environment.

    **Seeding.** ``reset(seed=s)``: environment k is the single environment reset with
    seed ``s + k``; ``reset(seed=[s_0, ...])`` one seed each (all ints, or all None);
    ``reset()`` continues every environment's own sequence (a first ``reset()`` uses the
    ``seed`` override, or 0). ``options`` are not used; a ``reset_mask`` (partial reset)
    is refused: environments reset themselves when their episode ends.

    **Automatic reset: same step** (``metadata["autoreset_mode"]``), reported as
    ``SyncVectorEnv`` does in that mode: where an episode ended, the returned observation
    is the new episode's first, ``infos["final_obs"]`` (object array, None elsewhere) holds
    the last one and ``infos["final_info"]`` the ended step's infos, each with its
    ``_key`` mask (``_final_obs``, ``_final_info``: the environments that ended). Both
    keys appear only on steps where some episode ended.

    **Infos** (dicts of arrays over environments, each key with its ``_key`` mask): the
    single view's team info (``CoopTransportGymEnv``, ``uvms_env.env.infos``) as (K,)
    arrays, the same keys every step: ``cost`` (violated safety constraints summed over
    the robots), ``reward_<term>``, ``episode_end`` (the end's code; 0 while an episode
    runs), ``diverged`` and the metrics (zeros until an episode's end); and
    ``constraint_values`` (K, N, C), each robot's g <= 0 values (the single view's
    per-agent ``"agents"`` infos are not built: this carries their content). Where an
    episode ended, ``final_info`` holds that step's values and the top level the new
    episode's first infos (zeros), as ``SyncVectorEnv`` reports a reset; ``reset`` gives
    the zeros and ``episode_seed`` (K,) int.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": [],
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        scenario: str | Scenario = "paper",
        dtype: str = "float64",
        threads: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None:
            raise ValueError(f"the vector environment does not render, got {render_mode=}")
        self.vector_env = VectorEnv(
            scenario, num_envs=num_envs, dtype=dtype, threads=threads, **overrides
        )
        self.num_envs = self.vector_env.num_envs
        self.n_agents = n = self.vector_env.n
        self.possible_agents = list(self.vector_env.possible_agents)
        obs = self.vector_env.single_observation_space
        act = self.vector_env.single_action_space
        self.single_observation_space = spaces.Box(
            np.tile(obs.low, n), np.tile(obs.high, n), dtype=np.float32
        )
        self.single_action_space = spaces.Box(-1.0, 1.0, (act.shape[0] * n,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        task = self.vector_env.task
        zeros = InfoLayout(task.constraints, task.reward_terms).reset(["team"])["team"]
        # the team's keys of a reset's infos (every key but the robots' constraint values)
        self._zeros = {k: v for k, v in zeros.items() if not k.startswith(CONSTRAINT_PREFIX)}
        self._metric_keys = metric_keys(task.constraints)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if options is not None and "reset_mask" in options:
            raise ValueError(
                "partial resets (options['reset_mask']) are not supported: environments reset "
                "themselves in the step their episode ends (AutoresetMode.SAME_STEP)"
            )
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            super().reset(seed=int(seed))  # seeds self.np_random as Gymnasium's envs do
        elif seed is not None:
            seeds = list(seed)
            if all(s is None for s in seeds) and len(seeds) == self.num_envs:
                seed = None
            elif any(s is None for s in seeds):
                raise ValueError(f"seed: all ints or all None, got {seeds}")
        obs, infos = self.vector_env.reset(seed=seed)
        k = self.num_envs
        zeros = {key: np.full(k, v, dtype=type(v)) for key, v in self._zeros.items()}
        zeros["episode_seed"] = np.asarray(infos["episode_seed"])
        return obs.reshape(k, -1), _masked(zeros, np.ones(k, bool))

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        k, n = self.num_envs, self.n_agents
        a = np.asarray(actions)
        if a.shape != self.action_space.shape:
            raise ValueError(f"actions must have shape {self.action_space.shape}, got {a.shape}")
        obs, reward, terminated, truncated, vinfos = self.vector_env.step(a.reshape(k, n, -1))
        ended = terminated | truncated
        step_info = self._team_info(vinfos, ended)
        if not ended.any():
            return obs.reshape(k, -1), reward, terminated, truncated, _masked(step_info, ~ended)
        # as SyncVectorEnv in same-step mode: the ended episodes' infos in final_info, the
        # new episodes' first (reset) infos at the top level
        infos = _masked({key: v.copy() for key, v in step_info.items()}, np.ones(k, bool))
        for key, value in self._zeros.items():
            infos[key][ended] = value
        ids = np.flatnonzero(ended).tolist()
        final_obs = np.full(k, None, dtype=object)
        last = vinfos["final_observation"].reshape(k, -1)
        for i in ids:
            final_obs[i] = last[i]
        infos["final_obs"], infos["_final_obs"] = final_obs, ended.copy()
        infos["final_info"], infos["_final_info"] = _masked(step_info, ended), ended.copy()
        return obs.reshape(k, -1), reward, terminated, truncated, infos

    def _team_info(self, vinfos: dict[str, Any], ended: np.ndarray) -> dict[str, np.ndarray]:
        """The single view's team info (``CoopTransportGymEnv``) of every environment, as
        arrays (K,): the robots' summed cost, the reward's terms, how the episode ended,
        whether its step was refused and the ended episodes' metrics (zeros elsewhere);
        and the robots' constraint values (K, N, C)."""
        k = self.num_envs
        out: dict[str, np.ndarray] = {"cost": vinfos["cost"].sum(axis=1)}
        for name, value in vinfos["reward_terms"].items():
            out[f"reward_{name}"] = np.broadcast_to(value, (k,)).astype(float)
        out["episode_end"] = np.array([end_code(e) if e else 0 for e in vinfos["episode_end"]])
        out["diverged"] = (vinfos["diverged_reason"] != "").astype(int) & ended
        for key in self._metric_keys:
            zero = self._zeros[key]
            column = np.full(k, zero, dtype=type(zero))
            for i in np.flatnonzero(ended).tolist():
                column[i] = vinfos["metrics"][i][key]
            out[key] = column
        out["constraint_values"] = vinfos["constraint_values"]
        return out

    def state(self) -> np.ndarray:
        """(K, 20 N + 19) float32: each environment's ``parallel_env.state()``."""
        return self.vector_env.state()

    def close_extras(self, **kwargs: Any) -> None:
        self.vector_env.close()


def _masked(values: dict[str, Any], mask: np.ndarray) -> dict[str, Any]:
    """``values`` with a ``_key`` mask next to every key, nested dicts included (the layout
    of ``gymnasium.vector.VectorEnv._add_info``)."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        out[key] = _masked(value, mask) if isinstance(value, dict) else value
        out[f"_{key}"] = mask.copy()
    return out
