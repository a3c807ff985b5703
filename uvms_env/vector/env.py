"""K cooperative-transport environments stepped together: the single environment, batched.

    from uvms_env.vector import VectorEnv
    venv = VectorEnv("paper", num_envs=256, dtype="float32")
    obs, infos = venv.reset(seed=0)                  # obs (K, N, 79) float32
    obs, reward, terminated, truncated, infos = venv.step(actions)   # actions (K, N, 8)

Environment k is ``parallel_env(scenario, **overrides)`` reset with seed ``seed + k``,
stepped with ``actions[k]``: in float64 the same episode step for step (docs/batched.md,
"Same episodes"). The class docstring lists what differs and what is returned.

The episode's flow is the single environment's (``uvms_env.env.core.EnvCore``) on
``uvms_env.vector.batched_engine.BatchedEngine``. Python runs per environment only where an
environment's own random generator must be drawn from (sensor noise, ocean current: a
loop over K when they are switched on, so that every draw is the single environment's)
and for environments whose episode ended. This module adds the array API: automatic
resets, the geometry pool, partial restarts and torch tensors on a GPU
(``backend="cuda"``: docs/batched.md, "On a GPU").

May import: numpy, gymnasium (spaces), torch (only to return tensors on the CUDA
backend), ``uvms_env`` below ``vector``, the ``env`` core and options, and the sibling
``vector`` modules.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from uvms_env.env.core import CoreViews, EnvCore
from uvms_env.env.options import (
    RESET_SEED,
    action_space,
    observation_space,
    observation_structure,
    resolve,
)
from uvms_env.scenarios import Scenario
from uvms_env.scenarios.overrides import Option
from uvms_env.vector.batched_engine import DIVERGED_REASONS, BatchedEngine
from uvms_env.vector.batched_simulator import BatchedSimulator, check_batch
from uvms_env.vector.kernels import available_cores

ALL = slice(None)  # every environment, as an index
VECTOR_OPTIONS: dict[str, Option] = {
    "geometry_pool": Option(
        "int", "seeded families: episodes cycle through this many bank seeds", low=1, optional=True
    ),
}
__all__ = ["DIVERGED_REASONS", "VECTOR_OPTIONS", "VectorEnv"]


class VectorEnv(CoreViews):
    """K environments of one scenario family and team size, stepped together.

    Construct: ``VectorEnv(scenario="paper", num_envs=1, backend="cpu", dtype="float64",
    threads=None, lanes=None, device=0, **overrides)``; the overrides are every keyword of
    ``parallel_env`` (scenario overrides and environment options, with the same checks)
    plus ``geometry_pool``. ``backend="cuda"``: on GPU ``device`` (module docstring); the
    arrays below are then torch tensors on that device, except the per-environment
    objects of ``infos`` (``episode_end``, ``metrics``, ``diverged_reason``) and
    ``episode_seed``, which stay numpy.

    | call | returns |
    |---|---|
    | `reset(seed=None)` | `obs` (K, N, 79) float32, `infos` (dict) |
    | `step(actions)`: (K, N, 8) in [-1, 1] | `obs`, `reward`, `terminated`, `truncated`, `infos` |
    | `state()` | (K, 20 N + 19) float32: each environment's `parallel_env.state()` |

    **Seeding.** `reset(seed=s)`: environment k starts as `parallel_env(...).reset(seed=s + k)`;
    `reset(seed=[s_0, ..., s_{K-1}])` gives each its seed; `reset()` continues every
    environment's own sequence, as the single env's `reset()` does. For the seeded
    families ("random", "short") environment k then has geometry `s + k`, built once
    and kept on disk by `uvms_env.scenarios.bank` (`python -m uvms_env.vector.build_bank` builds
    them ahead of time; a first build costs ~0.5 s per random geometry). The first
    `reset()` without a seed uses the `seed` override (or 0) as `s`.

    **Automatic reset** (same step, the Gymnasium `SAME_STEP` / SB3 convention): an
    environment whose episode ends is reset inside `step`; the returned `obs` row is the
    new episode's first observation and `infos["final_observation"]` holds the last
    one. By default the new episode is the single env's `reset()`: the same geometry,
    the next draws of the environment's own generator. With `geometry_pool=P` (seeded
    families; training), episode e of environment k (e = 0 after `reset(seed=s)`) is
    instead `reset(seed=(s + k + K e) % P)`: every episode a geometry from the bank's
    first P seeds.

    **Infos** (arrays over environments; a key is present every step):

    | key | shape | meaning |
    |---|---|---|
    | constraint_values | (K, N, 8 + E) | g <= 0 holds: `CONSTRAINTS`, then E extra ones |
    | cost | (K, N) | violated safety constraints per robot |
    | reward_terms | dict name -> (K,) | the terms of the shared reward (extra terms last) |
    | success | (K,) bool | the episode succeeded this step |
    | episode_end | (K,) object | "" or success, collision, constraint, diverged, max_cycles |
    | final_observation | (K, N, 79) | last observation of the envs that ended (else zeros) |
    | final_state | (K, 20 N + 19) or None | `state()` before the resets, when an env ended |
    | metrics | (K,) object | the ended episodes' flat metrics (`uvms_env.task.metrics`), or None |
    | diverged_reason | (K,) object | why a step was refused ("" elsewhere) |

    **Communication** (`comm=`): as in `parallel_env`, the same channel code over K: actions
    (K, N, 8 + 1 + D), observations with the inbox after them; an environment's automatic
    reset empties its channel and takes its next episode's loss key.

    **Extensions**: `extra_reward_terms` and `extra_constraints` as in `parallel_env`; the
    functions receive the K environments' arrays (CuPy ones on a GPU) and `xp`.

    **Float32** (`dtype="float32"`): every compiled call in single precision, rewards and
    metrics in float64 from its results; the fast mode. Its deviation from float64 is
    measured in the tests and the README.

    **Differences from K single envs.** No rendering. Per-environment geometries share
    the team size, the object, the period and the substeps (always so within a family
    and team size). `diverged_reason` names the kind of refusal but not the time and
    value. Threads: `threads` (default: every core this process may use).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": "same_step"}

    def __init__(
        self,
        scenario: str | Scenario = "paper",
        num_envs: int = 1,
        backend: str = "cpu",
        dtype: str = "float64",
        threads: int | None = None,
        lanes: int | None = None,
        device: int | str = 0,
        **overrides: Any,
    ) -> None:
        check_batch(num_envs, backend, dtype)
        self.backend, self.dtype = backend, dtype
        self.num_envs = k = int(num_envs)
        self.threads = int(threads) if threads is not None else available_cores()
        first = overrides.get("seed")
        setup = resolve(scenario, overrides, 0, VECTOR_OPTIONS, "vector")
        self.geometry_pool: int | None = setup.own.get("geometry_pool")
        if self.geometry_pool is not None and not setup.seeded:
            raise ValueError(
                "geometry_pool needs a seeded family (random, short) with reseed_geometry"
            )
        if self.geometry_pool is not None:
            # the first episodes' geometries, built now with a progress bar rather than
            # silently in the first reset; the rest of the pool as the episodes reach it
            # (a pool of 1024 random N = 6 geometries would take ~15 minutes up front)
            setup.prebuild(range(min(self.geometry_pool, int(num_envs))))
        self.family = setup.family
        self._first_seed = int(first or 0)
        self._engine = BatchedEngine(setup, k, backend, dtype, self.threads, lanes, device)
        self._core = EnvCore(setup, self._engine, k, [self._first_seed + i for i in range(k)])
        self.xp = self._engine.xp
        self.device = self._engine.device
        self.n = n = setup.n_agents
        self.possible_agents = [f"uvms_{i}" for i in range(n)]
        self.agents = list(self.possible_agents)
        self.comm = setup.comm  # the acoustic channel's settings (None: off)
        self.single_observation_space = observation_space(setup.priors, setup.comm)
        self.single_action_space = action_space(setup.comm)
        self.observation_structure = observation_structure(setup.priors, setup.comm)
        # episode bookkeeping of the resets (host: read in Python per ended environment)
        self._episode = np.zeros(k, np.int64)
        self._episode_base = np.zeros(k, np.int64)
        self._seeds_now = np.full(k, -1)  # the seeds of the last seeded reset (-1: none)
        self._started = False

    # -- what the core holds --------------------------------------------------------------
    @property
    def sim(self) -> BatchedSimulator:
        return self._engine.sim

    @property
    def scenarios(self) -> list[Scenario]:
        return self._core.scenarios

    @property
    def scenario(self) -> Scenario:
        """Environment 0's scenario (every environment's: ``scenarios``)."""
        return self._core.scenarios[0]

    def _export(self, a: Any) -> Any:
        """What ``reset``/``step`` return for a step array: numpy on the CPU backend,
        torch tensors on the CUDA backend's device (zero-copy through DLPack)."""
        if self.backend == "cpu" or a is None:
            return a
        import torch

        if self.xp is np:  # the emulated device: torch on the host
            return torch.from_numpy(np.ascontiguousarray(a))
        return torch.from_dlpack(a)

    # -- spaces and views ---------------------------------------------------------------
    @property
    def observation_space(self) -> spaces.Box:
        one = self.single_observation_space
        shape = (self.num_envs, self.n, *one.shape)
        return spaces.Box(
            np.broadcast_to(one.low, shape), np.broadcast_to(one.high, shape), shape, np.float32
        )

    @property
    def action_space(self) -> spaces.Box:
        size = self.single_action_space.shape[0]
        return spaces.Box(-1.0, 1.0, (self.num_envs, self.n, size), np.float32)

    def state(self) -> Any:
        """(K, 20 N + 19) float32: the true state, the team's waypoint and the time
        fraction of every environment, as ``parallel_env.state()`` (a torch tensor on the
        CUDA backend)."""
        return self._export(self._core.state())

    # -- episodes -----------------------------------------------------------------------
    def reset(
        self, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Start an episode in every environment (see Seeding; ``options`` is unused)."""
        k = self.num_envs
        every = list(range(k))
        if seed is None and not self._started:
            seed = self._first_seed
        if seed is None and self.geometry_pool is not None:  # every env: its next episode
            self._autoreset(np.arange(k))
            self._started = True
            return self._export(self._core.view(ALL)), {
                "episode_seed": self._pool_seeds(np.arange(k))
            }
        self._started = True
        if seed is not None:
            self._start(np.arange(k), self._seed_list(seed))
        else:
            self._core.reset(every)
        return self._export(self._core.view(ALL)), {"episode_seed": self._seeds_now.copy()}

    def _start(self, ids: np.ndarray, seeds: list[int]) -> None:
        """Environments ``ids`` start episode 0 of their ``seeds`` (with a geometry pool,
        the pool's seed of it), as ``reset(seed=...)`` does."""
        self._episode_base[ids] = seeds
        self._episode[ids] = 0
        if self.geometry_pool is not None:
            seeds = self._pool_seeds(ids).tolist()
        self._seeds_now[ids] = seeds
        rows = ids.tolist()
        self._core.seed(rows, seeds)
        self._core.reset(rows)

    def _seed_list(self, seed: int | Sequence[int]) -> list[int]:
        k = self.num_envs
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            base = RESET_SEED.check("seed", seed)
            return [base + i for i in range(k)]
        try:
            seeds = list(seed)  # type: ignore[arg-type]
        except TypeError:
            raise TypeError(f"seed must be None, an int >= 0 or {k} ints, got {seed!r}") from None
        if len(seeds) != k:
            raise ValueError(f"reset got {len(seeds)} seeds for {k} environments")
        return [RESET_SEED.check(f"seed of environment {i}", s) for i, s in enumerate(seeds)]

    # -- stepping -------------------------------------------------------------------------
    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("step() called before reset()")
        xp, k, n, core = self.xp, self.num_envs, self.n, self._core
        out, diverged = core.step(core.check_actions(self._as_array(actions)))
        ended = out.terminated | out.truncated
        final_obs = xp.zeros((k, n, *self.single_observation_space.shape), np.float32)
        infos: dict[str, Any] = {
            "constraint_values": out.constraint_values,
            "cost": out.cost,
            "reward_terms": out.terms,
            "success": out.success,
            "episode_end": np.full(k, "", dtype=object),
            "final_observation": final_obs,
            "final_state": None,
            "metrics": np.full(k, None, dtype=object),
            "diverged_reason": np.full(k, "", dtype=object),
        }
        if bool(ended.any()):
            done = np.flatnonzero(self._core.host(ended))
            on = core.ids_of(done.tolist())
            infos["final_observation"][on] = core.view(on)
            infos["final_state"] = core.state()  # before the reset, for central critics
            kinds, metrics, reasons = core.ended(done.tolist(), out, diverged)
            infos["episode_end"][done] = kinds
            infos["metrics"][done] = metrics
            infos["diverged_reason"][done] = reasons
            self._autoreset(done)
        if self.backend == "cuda":
            for key in ("constraint_values", "cost", "success", "final_observation", "final_state"):
                infos[key] = self._export(infos[key])
            infos["reward_terms"] = {
                name: self._export(xp.broadcast_to(v, (k,)).copy()) for name, v in out.terms.items()
            }
        return (
            self._export(core.view(ALL)),
            self._export(out.reward),
            self._export(out.terminated),
            self._export(out.truncated),
            infos,
        )

    def restart(self, env_ids: Any, seeds: Sequence[int] | None = None) -> Any:
        """End the episodes of ``env_ids`` where they stand and start their next ones, as the
        automatic reset does (a partial reset, e.g. for TorchRL's ``_reset`` mask); returns
        their first observations (len(env_ids), N, 79). The other environments go on.
        ``seeds`` (one per id, in the ids' order): each restarts as ``reset(seed=...)``
        starts it (a seeded family: that seed's geometry, or with a geometry pool the
        pool's seed of it), as an evaluator that hands an ended copy its next seeded
        episode needs."""
        if not self._started:
            raise RuntimeError("restart() called before reset()")
        raw = np.asarray(env_ids, dtype=np.int64).reshape(-1)
        ids = np.unique(raw)
        if len(ids) and (ids[0] < 0 or ids[-1] >= self.num_envs):
            raise ValueError(f"env_ids must lie in 0..{self.num_envs - 1}, got {env_ids!r}")
        if seeds is not None:
            seeds = list(seeds)
            if len(seeds) != len(raw) or len(ids) != len(raw):
                raise ValueError(
                    f"restart got {len(seeds)} seeds for {len(raw)} env ids "
                    "(one seed per id, no id twice)"
                )
            checked = [
                RESET_SEED.check(f"seed of environment {i}", s)
                for i, s in zip(raw, seeds, strict=True)
            ]
            self._start(raw, checked)
            on = raw if self.xp is np else self.xp.asarray(raw)
            return self._export(self._core.view(on))
        if len(ids):
            self._autoreset(ids)
        on = ids if self.xp is np else self.xp.asarray(ids)
        return self._export(self._core.view(on))

    def _autoreset(self, ids: np.ndarray) -> None:
        self._episode[ids] += 1
        rows = ids.tolist()
        if self.geometry_pool is not None:
            self._core.seed(rows, self._pool_seeds(ids).tolist())
        self._core.reset(rows)

    def _pool_seeds(self, ids: np.ndarray) -> np.ndarray:
        """The reset seeds of the current episodes of ``ids`` with a geometry pool."""
        assert self.geometry_pool is not None
        raw = self._episode_base[ids] + self.num_envs * self._episode[ids]
        return raw % self.geometry_pool

    def _as_array(self, actions: Any) -> Any:
        """Actions as the step's array type: numpy, or on the GPU without a copy where they
        are there already (torch CUDA tensors and CuPy arrays, through DLPack)."""
        xp = self.xp
        is_torch = type(actions).__module__.startswith("torch")
        try:
            if xp is np:
                return np.asarray(actions.detach().cpu() if is_torch else actions)
            if is_torch and actions.is_cuda:
                return xp.from_dlpack(actions.detach())
            return xp.asarray(actions.detach().cpu().numpy() if is_torch else actions)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"actions must be an array of shape ({self.num_envs}, {self.n}, "
                f"{self._core.action_size})"
            ) from exc

    def close(self) -> None:
        """Nothing to release (no windows, no processes); for the Gymnasium contract."""
