"""Gymnasium's vector API over a ``VectorEnv``: the centralized view, K environments at once.

    import gymnasium, uvms_env
    envs = gymnasium.make_vec("uvms_env/CoopTransport-v0", num_envs=64, scenario="short",
                              dtype="float32")       # vectorization_mode: vector_entry_point
    obs, infos = envs.reset(seed=0)                  # obs (64, 79 N)
    obs, rewards, terminations, truncations, infos = envs.step(actions)   # actions (64, 8 N)

Each environment is the single Gymnasium environment (``uvms_env.env.gym_wrapper``): the
robots' observations concatenated, their actions concatenated, the team reward. It is
centralized by construction; ``uvms_env.vector.sb3`` gives the decentralized, shared-policy
view for SB3.

May import: numpy, gymnasium and ``uvms_env.vector.env``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector import VectorEnv as GymVectorEnv
from gymnasium.vector.utils import batch_space

from uvms_env.scenarios import Scenario
from uvms_env.vector.env import VectorEnv


class CoopTransportVectorEnv(GymVectorEnv):
    """``gymnasium.vector.VectorEnv`` of K centralized ``uvms_env/CoopTransport-v0`` envs.

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

    **Infos** (dicts of arrays over environments, each key with its ``_key`` mask):

    | key | shape | where |
    |---|---|---|
    | reward_terms | dict name -> (K,) | every step |
    | cost | (K,) int | every step: violated constraints, summed over the robots |
    | constraint_values | (K, N, 8) | every step: each robot's g <= 0 values |
    | episode_end | (K,) object | in ``final_info`` only |
    | metrics | dict name -> (K,) | in ``final_info`` only (``uvms_env.task.metrics``) |
    | diverged_reason | (K,) object | in ``final_info``, for refused steps |
    | episode_seed | (K,) int | ``reset`` |

    As in ``SyncVectorEnv``, the top-level masks are False for the environments that
    ended (their step infos are in ``final_info``); the arrays hold every environment's
    values all the same. The single environment's per-agent ``"agents"`` infos are not
    built (``constraint_values`` carries their content as an array).
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
        mask = np.ones(self.num_envs, bool)
        return obs.reshape(self.num_envs, -1), {
            "episode_seed": np.asarray(infos["episode_seed"]),
            "_episode_seed": mask,
        }

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        k, n = self.num_envs, self.n_agents
        a = np.asarray(actions)
        if a.shape != self.action_space.shape:
            raise ValueError(f"actions must have shape {self.action_space.shape}, got {a.shape}")
        obs, reward, terminated, truncated, vinfos = self.vector_env.step(a.reshape(k, n, -1))
        ended = terminated | truncated
        step_info = {
            "reward_terms": vinfos["reward_terms"],
            "cost": vinfos["cost"].sum(axis=1),
            "constraint_values": vinfos["constraint_values"],
        }
        infos = _masked(step_info, ~ended)
        if ended.any():
            ids = np.flatnonzero(ended).tolist()
            final_obs = np.full(k, None, dtype=object)
            last = vinfos["final_observation"].reshape(k, -1)
            for i in ids:
                final_obs[i] = last[i]
            final = {
                **_copied(step_info),
                "episode_end": np.where(ended, vinfos["episode_end"], None),
            }
            final_info = _masked(final, ended)
            final_info["metrics"] = _stacked([vinfos["metrics"][i] for i in ids], ids, k)
            final_info["_metrics"] = ended.copy()
            diverged = vinfos["diverged_reason"] != ""
            if (diverged & ended).any():
                final_info["diverged_reason"] = np.where(diverged, vinfos["diverged_reason"], None)
                final_info["_diverged_reason"] = diverged & ended
            infos["final_obs"], infos["_final_obs"] = final_obs, ended.copy()
            infos["final_info"], infos["_final_info"] = final_info, ended.copy()
        return obs.reshape(k, -1), reward, terminated, truncated, infos

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


def _stacked(dicts: list[dict[str, Any]], ids: list[int], k: int) -> dict[str, Any]:
    """The dicts of environments ``ids`` as one dict of (K,) arrays with ``_key`` masks, as
    ``_add_info`` batches a dict-valued info: numbers in an array of their type (zeros
    elsewhere), anything else (None, str) in an object array (None elsewhere)."""
    mask = np.zeros(k, bool)
    mask[ids] = True
    out: dict[str, Any] = {}
    for key in dicts[0]:
        values = [d[key] for d in dicts]
        if all(isinstance(v, dict) for v in values):
            out[key] = _stacked(values, ids, k)
        else:
            kinds = {type(v) for v in values}
            number = len(kinds) == 1 and issubclass(kinds.pop(), int | float | bool | np.number)
            array = np.zeros(k, type(values[0])) if number else np.full(k, None, object)
            array[ids] = values
            out[key] = array
        out[f"_{key}"] = mask.copy()
    return out


def _copied(values: dict[str, Any]) -> dict[str, Any]:
    return {
        key: _copied(value) if isinstance(value, dict) else np.array(value, copy=True)
        for key, value in values.items()
    }
