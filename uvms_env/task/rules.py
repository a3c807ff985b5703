"""The task's rules, written once: array code over K environments, any array namespace.

``Task`` applies the rules of the task to K environments, as arrays of the namespace
``xp`` it is given (numpy, or CuPy on a GPU), one part per concern: the waypoint
sequencing (``Sequencing``, ``uvms_env.task.sequencing``), the metrics' tallies
(``Tally``, ``uvms_env.task.tally``), and here the constraint bookkeeping, success and
episode ends, and the shared reward (``uvms_env.task.reward``).
Reference: docs/environment.md, "The task and its driver" and "Extension points".

``parallel_env`` runs one for a single environment without the batch axis
(``num_envs=None``: the same code, on numpy scalars rather than 1-element arrays, which
cost several times more per operation). Nothing here is per-environment Python.

May import: numpy, ``uvms_env.dynamics`` (compiled) and the other modules of
``uvms_env.task`` except ``team_kernel``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.task.constraints import CONSTRAINTS, HARD_CONSTRAINTS
from uvms_env.task.reward import REWARD_TERMS, RewardWeights
from uvms_env.task.sequencing import Sequencing
from uvms_env.task.tally import Tally
from uvms_env.task.team_rows import (
    ACTION_SQ,
    ALL,
    ANY_VIOLATED,
    AT_GOAL,
    EXCESS,
    KINDS,
    MAX_EXCESS,
    PASSED,
    POTENTIAL,
    POTENTIAL_AFTER,
    VIOLATED,
    VIOLATED_ROBOTS,
)

HARD_KINDS = [CONSTRAINTS.index(c) for c in HARD_CONSTRAINTS]  # indices of HARD_CONSTRAINTS

TaskFunction = Callable[["TaskArrays", Any], Any]


@dataclass(frozen=True)
class TaskArrays:
    """What an extra reward term or constraint sees, K environments of N robots (K = 1 for
    a single env; float64 arrays of ``xp``; the true state after the step).

    object_pose (K, 6): p_O, Theta_O; q, zeta (K, N, 10): each robot's generalized
    coordinates and velocities; action (K, N, 8): the requested normalized inputs;
    waypoint (K, 6): the team's active waypoint (a reward term sees it after this step's
    sequencing, a constraint before), goal (K, 6);
    steps (K,): periods played; success, failed (K,) bool: None for constraints (they are
    decided from them)."""

    object_pose: Any
    q: Any
    zeta: Any
    action: Any
    waypoint: Any
    goal: Any
    steps: Any
    success: Any = None
    failed: Any = None


class StepOutcome(NamedTuple):
    """One step's results (arrays of the task's namespace, batch shape B in front)."""

    reward: Any  # B
    terms: dict[str, Any]  # name -> B, REWARD_TERMS then the extra terms
    constraint_values: Any  # B + (N, C): C = 8 + extra constraints
    cost: Any  # B + (N,) violated safety constraints per robot
    success: Any  # B bool
    failed: Any
    collision: Any
    terminated: Any
    truncated: Any


def resolve_function(name: str, fn: Any) -> TaskFunction:
    """``fn`` itself when callable; ``"package.module:function"`` imported."""
    if callable(fn):
        return fn
    if not isinstance(fn, str) or fn.count(":") != 1:
        raise TypeError(f"{name}: expected a callable or 'module:function', got {fn!r}")
    module, attr = fn.split(":")
    try:
        out = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"{name}: cannot import {fn!r}: {exc}") from exc
    if not callable(out):
        raise TypeError(f"{name}: {fn!r} is not callable")
    return out


#: How an ended episode can end (``infos["episode_end"]``), in the order ``episode_end``
#: tests them.
EPISODE_ENDS = ("success", "diverged", "collision", "constraint", "max_cycles")


def episode_end(success: bool, diverged: bool, collision: bool, failed: bool) -> str:
    """How an ended episode ended (``infos["episode_end"]``): the first of ``EPISODE_ENDS``
    that applies, success, diverged, collision, constraint (another failure), max_cycles."""
    flags = (success, diverged, collision, failed, True)
    return next(kind for kind, flag in zip(EPISODE_ENDS, flags, strict=True) if flag)


class Task(NamespacePickled):
    """The task's state and rules over K environments of N robots (module docstring).

    ``xp``: numpy or CuPy. ``num_envs``: K, or None for one environment without a batch
    axis: the batch shape B is (K,) or (), and every array and result has it in front
    (B = (): numpy scalars). ``w_max``: room for waypoints per environment.
    Parts: ``sequencing`` (waypoints, the team's and each robot's sequencer; its arrays
    ``waypoints``, ``robot_index``, ``team_waypoint`` and ``goal`` are
    read here too) and ``tally`` (the metrics' accumulators); here ``steps`` B and the
    reward's ``potential`` B. Inputs are in the same shapes: ``team`` (T,) + B, the
    kinematics kernel's team rows (``uvms_env.task.team_rows``).

    Calls, in an episode's order: ``set_geometry`` (when a geometry changes), ``reset``
    (bookkeeping), then per evaluation of the kinematics kernel ``observe`` (state metrics;
    the kernel itself advances each robot's sequencer, ``sequencing.robots``, and computes
    the team's next one, its potentials and the goal test); ``start`` after the first one
    (the team's sequencer and the reward's potential taken from it); per step ``tick``
    (before the kernel: time advances; it says where the internal wrench is sampled),
    ``step`` (after it) and ``results`` and ``end_kinds`` for the episodes that ended.
    ``ids``: a slice or an index array of the namespace."""

    def __init__(
        self,
        xp: Any,
        num_envs: int | None,
        n_agents: int,
        w_max: int,
        *,
        weights: RewardWeights,
        constraint_mode: str,
        max_cycles: int,
        period: float,
        success_pos_tol: float,
        success_att_tol: float,
        internal_wrench_every: int = 1,
        extra_reward_terms: Mapping[str, Any] | None = None,
        extra_constraints: Mapping[str, Any] | None = None,
    ) -> None:
        self.xp = xp
        self.num_envs = num_envs
        self.batch = b = () if num_envs is None else (num_envs,)
        self.n = n_agents
        self.weights = weights
        self.terminate = constraint_mode == "terminate"
        self.max_cycles = max_cycles
        self.period = period
        self.wrench_every = internal_wrench_every
        # violations averaged over robots, effort over robots and inputs
        self._per_violation = weights.violation / n_agents
        self._per_action_sq = weights.effort / (n_agents * NU)
        self.reward_fns = _functions("extra_reward_terms", extra_reward_terms, REWARD_TERMS)
        self.constraint_fns = _functions("extra_constraints", extra_constraints, CONSTRAINTS)
        self.reward_terms = REWARD_TERMS + tuple(self.reward_fns)
        self.constraints = CONSTRAINTS + tuple(self.constraint_fns)
        self.extended = bool(self.reward_fns or self.constraint_fns)
        self.sequencing = Sequencing(
            xp, b, n_agents, w_max, (weights.attitude, success_pos_tol, success_att_tol)
        )
        self.tally = Tally(xp, b, len(self.constraints), n_agents)
        self._hard_many = len(HARD_KINDS) > 1
        self._hard = HARD_KINDS if self._hard_many else HARD_KINDS[0]
        self.steps = xp.zeros(b, np.int64)
        self.potential = xp.zeros(b)

    def _any(self, mask: Any) -> bool:
        """A host test of a mask of shape B (B = (): a numpy scalar, tested as one)."""
        return self.sequencing.any(mask)

    # the sequencing's arrays the episode's flow reads (views, not copies)
    @property
    def waypoints(self) -> Any:
        return self.sequencing.waypoints

    @property
    def robot_index(self) -> Any:
        return self.sequencing.robot_index

    @property
    def team_waypoint(self) -> Any:
        return self.sequencing.team_waypoint

    @property
    def goal(self) -> Any:
        return self.sequencing.goal

    # -- geometry and resets -------------------------------------------------------------
    def set_geometry(self, ids: Any, waypoints: Any, counts: Any) -> None:
        """Environments ``ids`` take these waypoints (B' + (W, 6), zeros beyond each one's
        ``counts`` B'): host or device arrays."""
        self.sequencing.set_geometry(ids, waypoints, counts)

    def reset(self, ids: Any) -> None:
        """New episodes in ``ids``: time, metrics, every robot back to its first waypoint."""
        self.steps[ids] = 0
        self.tally.reset(ids)
        self.sequencing.reset(ids)

    def start(self, ids: Any, team_rows: Any) -> None:
        """After a reset's first kinematics call (its team rows ``team_rows`` (T,) + B'):
        the team's sequencer takes what it saw of the true object, the reward's potential
        starts there."""
        self.sequencing.commit(ids, team_rows)
        self.potential[ids] = team_rows[POTENTIAL_AFTER]

    # -- evaluation of the state --------------------------------------------------------
    def observe(self, ids: Any, team_rows: Any) -> None:
        """The state metrics, from the kinematics kernel's team rows (T,) + B' of ``ids``."""
        self.tally.observe(ids, team_rows)

    def tick(self, diverged: Any) -> Any:
        """A period passed in every environment (before the step's evaluation); returns
        where the internal wrench is sampled this step (B bool; None: never)."""
        self.steps += 1
        if self.wrench_every <= 0:
            return None
        return ~diverged & (self.steps % self.wrench_every == 0)

    def time_fraction(self, ids: Any = ALL) -> Any:
        return self.steps[ids] / self.max_cycles

    # -- one step ---------------------------------------------------------------------------
    def step(
        self,
        team_rows: Any,
        constraint_values: Any,
        cost: Any,
        diverged: Any,
        sampled: Any = None,
        wrench_sq: Any = None,
        state: TaskArrays | None = None,
    ) -> StepOutcome:
        """The rules of one step of every environment, after ``tick`` and the evaluation:
        ``team_rows`` (T,) + B float64 the kernel's team rows,
        ``constraint_values`` B + (N, 8) and ``cost`` B + (N,) the kernel's, ``diverged`` B
        (bool) the refused steps, ``sampled``/``wrench_sq`` B the internal wrench samples
        (``tick``), ``state`` what the extensions see (needed when ``extended``)."""
        xp = self.xp
        kinds = team_rows[KINDS].T > 0.0  # B + (8,)
        n_violated = team_rows[VIOLATED]
        graded = (
            team_rows[EXCESS].T,
            team_rows[MAX_EXCESS].T,
            team_rows[VIOLATED_ROBOTS].T,
            team_rows[ANY_VIOLATED],
        )
        if self.constraint_fns:
            assert state is not None, "extra constraints need the state"
            extra = self.extra_constraint_values(state)
            violated = extra > 0.0
            constraint_values = xp.concatenate([constraint_values, extra], axis=-1)
            cost = cost + violated.sum(axis=-1)
            kinds = xp.concatenate([kinds, violated.any(axis=-2)], axis=-1)
            n_violated = n_violated + violated.sum(axis=(-2, -1))
            graded = self._with_extra(graded, xp.maximum(extra, 0.0), violated, cost)
        hard = kinds[..., self._hard]
        collision = hard.any(axis=-1) if self._hard_many else hard
        failed = diverged | collision
        if self.terminate:
            failed = failed | (n_violated > 0)
        success = (team_rows[AT_GOAL] > 0.0) & ~failed
        terminated = success | failed
        truncated = (self.steps >= self.max_cycles) & ~terminated
        action_sq = team_rows[ACTION_SQ]
        self.tally.add_step(kinds, graded, action_sq * self.period, sampled, wrench_sq)
        self.sequencing.commit(ALL, team_rows)
        terms = self._reward_terms(team_rows, success, failed, n_violated, action_sq, state)
        values = iter(terms.values())
        reward = next(values)
        for value in values:  # in order: REWARD_TERMS, then the extra terms
            reward = reward + value
        self.tally.add_reward(reward)
        return StepOutcome(
            reward,
            terms,
            constraint_values,
            cost,
            success,
            failed,
            collision,
            terminated,
            truncated,
        )

    def _with_extra(self, graded: tuple, excess: Any, violated: Any, cost: Any) -> tuple:
        """The kernel's graded rows with the extra constraints' (scale 1: their own
        units) after them; any safety kind of a robot, extra ones included, from its
        ``cost`` (B + (N,), every kind it counts)."""
        xp = self.xp
        summed, largest, robots, _ = graded
        return (
            xp.concatenate([summed, excess.sum(axis=-2)], axis=-1),
            xp.concatenate([largest, excess.max(axis=-2)], axis=-1),
            xp.concatenate([robots, violated.sum(axis=-2)], axis=-1),
            (cost > 0).sum(axis=-1),
        )

    def _reward_terms(
        self,
        team_rows: Any,
        success: Any,
        failed: Any,
        n_violated: Any,
        action_sq: Any,
        state: TaskArrays | None,
    ) -> dict[str, Any]:
        """The shared reward's terms (``uvms_env.task.reward``), then the extra ones, from
        the kernel's team rows: the potential towards the waypoint the team held, and where
        its sequencer passed one this step; moves the potential on."""
        xp, w = self.xp, self.weights
        # potential-based progress towards the team's waypoint
        progress = w.progress * (self.potential - team_rows[POTENTIAL])
        self.potential[...] = team_rows[POTENTIAL_AFTER]
        terms = {
            "progress": progress,
            "waypoint": team_rows[PASSED] * w.waypoint,
            "success": success * w.success,
            # 0.0 - ...: a clean 0.0 rather than -0.0 when nothing is violated
            "violation": 0.0
            - self._per_violation * n_violated
            - failed * w.failure_penalty(self.max_cycles - self.steps, len(self.constraint_fns)),
            "effort": 0.0 - self._per_action_sq * action_sq,
        }
        if self.reward_fns:
            assert state is not None, "extra reward terms need the state"
            seen = replace(
                state,
                waypoint=xp.reshape(self.team_waypoint, (-1, 6)),
                success=xp.reshape(success, (-1,)),
                failed=xp.reshape(failed, (-1,)),
            )
            for name, fn in self.reward_fns.items():
                value = xp.asarray(fn(seen, xp), dtype=float)
                one = xp.broadcast_to(value, (self.num_envs or 1,))  # K = 1: a single env
                terms[name] = xp.reshape(one, self.batch)
        return terms

    def extra_constraint_values(self, state: TaskArrays) -> Any:
        """B + (N, E): the user's extra constraints of ``state`` (the functions see K = 1
        for a single environment; their values take the batch shape here)."""
        xp, shape = self.xp, (*self.batch, self.n)
        return xp.stack(
            [
                xp.reshape(xp.asarray(fn(state, xp), dtype=float), shape)
                for fn in self.constraint_fns.values()
            ],
            axis=-1,
        )

    # -- ended episodes ---------------------------------------------------------------------
    def results(self, ids: Any, x_o: Any, success: Any) -> list[dict[str, Any]]:
        """The metrics dicts of the episodes ``ids`` that ended at poses ``x_o`` B' + (6,)."""
        return self.tally.results(
            ids, self.steps[ids], x_o, self.goal[ids], success, self.period, self.constraints
        )

    def end_kinds(self, ids: Any, out: StepOutcome, diverged: Any) -> list[str]:
        """``episode_end`` of the environments ``ids``, from one host copy of the flags."""
        xp = self.xp
        flags = self.host(
            xp.stack([out.success[ids], diverged[ids], out.collision[ids], out.failed[ids]])
        ).reshape(4, -1)
        return [episode_end(*(bool(f) for f in col)) for col in flags.T.tolist()]


def _functions(
    option: str, fns: Mapping[str, Any] | None, taken: tuple[str, ...]
) -> dict[str, TaskFunction]:
    out = {}
    for name, fn in (fns or {}).items():
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"{option}: names must be identifiers, got {name!r}")
        if name in taken:
            raise ValueError(f"{option}: {name!r} is a built-in name ({', '.join(taken)})")
        out[name] = resolve_function(f"{option}[{name!r}]", fn)
    return out
