"""The task's rules, written once: array code over K environments, any array namespace.

``Task`` holds the episode bookkeeping of K environments as arrays of the namespace
``xp`` it is given (numpy, or CuPy on a GPU) and applies the rules of the task to them:
waypoint sequencing, constraint bookkeeping, success and episode ends, the shared reward
(``uvms_env.task.reward``), the metrics (``uvms_env.task.metrics``) and the resets.
Reference: docs/environment.md, "The task and its driver" and "Extension points".

``parallel_env`` runs one for a single environment without the batch axis
(``num_envs=None``: the same code, on numpy scalars rather than 1-element arrays, which
cost several times more per operation). Nothing here is per-environment Python.

May import: numpy, ``uvms_env.dynamics.spatial`` and the ``env`` modules of constants and
formulas it applies (constraints, metrics, reward, observation).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import NamespacePickled
from uvms_env.dynamics.spatial import wrap_angle
from uvms_env.navigation.task_navigator import WAYPOINT_TOLERANCE
from uvms_env.task.constraints import CONSTRAINTS, HARD_CONSTRAINTS
from uvms_env.task.metrics import episode_result
from uvms_env.task.reward import REWARD_TERMS, RewardWeights

NK = len(CONSTRAINTS)
HARD_KINDS = [CONSTRAINTS.index(c) for c in HARD_CONSTRAINTS]  # indices of HARD_CONSTRAINTS
# Rows of the kinematics kernel's team output (``TeamKinematics.team_rows``), (T,) + B.
CLEARANCE, MANIPULABILITY, GRASP_ERROR, WAYPOINT_DISTANCE2, VIOLATED, ACTION_SQ = range(6)
KINDS = slice(6, 6 + NK)
ALL = ...  # every environment, as an index (also of a single environment's 0-d arrays)

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
    cost: Any  # B + (N,) violated constraints per robot
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


def episode_end(success: bool, diverged: bool, collision: bool, failed: bool) -> str:
    """How an ended episode ended (``infos["episode_end"]``), the first that applies of
    success, diverged, collision, constraint (another failure), max_cycles."""
    if success:
        return "success"
    if diverged:
        return "diverged"
    if collision:
        return "collision"
    return "constraint" if failed else "max_cycles"


class Task(NamespacePickled):
    """The task's state and rules over K environments of N robots (module docstring).

    ``xp``: numpy or CuPy. ``num_envs``: K, or None for one environment without a batch
    axis: the batch shape B is (K,) or (), and every array and result has it in front
    (B = (): numpy scalars). ``w_max``: room for waypoints per environment.
    Arrays: ``waypoints`` B + (W, 6), ``team_waypoint`` and ``goal`` B + (6,),
    ``robot_index`` B + (N,), ``robot_waypoint`` B + (N, 6), ``steps`` B and the metrics'
    accumulators. Inputs are in the same shapes: ``team`` (T,) + B, ``x_o`` B + (6,).

    Calls, in an episode's order: ``set_geometry`` (when a geometry changes), ``reset``
    (bookkeeping), then per evaluation of the kinematics kernel ``observe`` (state metrics)
    and ``advance_robots``; ``start`` after the first one (the team's sequencing, the
    reward's potential); per step ``tick`` (before the kernel: time advances; it says
    where the internal wrench is sampled), ``step`` (after it) and ``results`` and
    ``end_kinds`` for the episodes that ended. ``ids``: a slice or an index array of
    the namespace."""

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
        self.n = n = n_agents
        self.weights = weights
        self.terminate = constraint_mode == "terminate"
        self.max_cycles = max_cycles
        self.period = period
        self.pos_tol, self.att_tol = success_pos_tol, success_att_tol
        self.wrench_every = internal_wrench_every
        # violations averaged over robots, effort over robots and inputs
        self._per_violation = weights.violation / n_agents
        self._per_action_sq = weights.effort / (n_agents * NU)
        self.reward_fns = _functions("extra_reward_terms", extra_reward_terms, REWARD_TERMS)
        self.constraint_fns = _functions("extra_constraints", extra_constraints, CONSTRAINTS)
        self.reward_terms = REWARD_TERMS + tuple(self.reward_fns)
        self.constraints = CONSTRAINTS + tuple(self.constraint_fns)
        self.extended = bool(self.reward_fns or self.constraint_fns)
        # numpy: skip the rare branches (a waypoint reached, the goal near) with one host
        # test; on a GPU that test would cost a synchronization, so they always run
        self._host_tests = xp is np
        self._hard_many = len(HARD_KINDS) > 1
        self._hard = HARD_KINDS if self._hard_many else HARD_KINDS[0]
        self._rows = xp.arange(num_envs) if b else None
        self.waypoints = xp.zeros((*b, w_max, 6))
        self.waypoint_count = xp.ones(b, np.int64)
        # the team's active waypoint and the goal side by side: one difference serves both
        self.targets = xp.zeros((*b, 2, 6))
        self.has_obstacles = xp.zeros(b, bool)
        self.steps = xp.zeros(b, np.int64)
        self.team_index = xp.zeros(b, np.int64)
        self.team_done = xp.zeros(b, bool)
        self.potential = xp.zeros(b)
        self.robot_index = xp.zeros((*b, n), np.int64)
        self.robot_done = xp.zeros((*b, n), bool)
        self.robot_waypoint = xp.zeros((*b, n, 6))
        self.min_clearance = xp.zeros(b)
        self.min_manipulability = xp.zeros(b)
        self.grasp_drift = xp.zeros(b)
        self.violations = xp.zeros((*b, len(self.constraints)), np.int64)
        self.effort = xp.zeros(b)
        self.wrench_sq = xp.zeros(b)
        self.wrench_samples = xp.zeros(b, np.int64)

    def _any(self, mask: Any) -> bool:
        """A host test of a mask of shape B (B = (): a numpy scalar, tested as one)."""
        return bool(mask.any()) if self.batch else bool(mask)

    @property
    def team_waypoint(self) -> Any:
        """B + (6,): the team's active waypoint (a view)."""
        return self.targets[..., 0, :]

    @property
    def goal(self) -> Any:
        """B + (6,): the final waypoint (a view)."""
        return self.targets[..., 1, :]

    def _waypoint_at(self, ids: Any, index: Any) -> Any:
        """The waypoints of environments ``ids`` at ``index`` (shape B' or B' + (N,))."""
        if not self.batch:
            return self.waypoints[index]
        rows = self._rows[ids]
        return self.waypoints[rows[:, None] if index.ndim == 2 else rows, index]

    # -- geometry and resets -------------------------------------------------------------
    def set_geometry(self, ids: Any, waypoints: Any, counts: Any, has_obstacles: Any) -> None:
        """Environments ``ids`` take these waypoints (B' + (W, 6), zeros beyond each one's
        ``counts`` B') and obstacle flags B': host or device arrays."""
        xp = self.xp
        self.waypoints[ids] = xp.asarray(waypoints)
        self.waypoint_count[ids] = xp.asarray(counts)
        self.has_obstacles[ids] = xp.asarray(has_obstacles)
        self.goal[ids] = self._waypoint_at(ids, self.waypoint_count[ids] - 1)

    def reset(self, ids: Any) -> None:
        """New episodes in ``ids``: time, metrics, every robot back to its first waypoint."""
        self.steps[ids] = 0
        self.min_clearance[ids] = np.inf
        self.min_manipulability[ids] = np.inf
        self.grasp_drift[ids] = 0.0
        self.violations[ids] = 0
        self.effort[ids] = 0.0
        self.wrench_sq[ids] = 0.0
        self.wrench_samples[ids] = 0
        self.robot_index[ids] = 0
        self.robot_done[ids] = False
        self.robot_waypoint[ids] = self.waypoints[ids][..., :1, :]
        self.team_index[ids] = 0
        self.team_done[ids] = False

    def start(self, ids: Any, x_o: Any) -> None:
        """After a reset's first evaluation: the team's sequencer sees the true object
        ``x_o`` B' + (6,) and the reward's potential starts there."""
        self.team_waypoint[ids] = self.waypoints[ids][..., 0, :]
        self._advance_team(ids, self._distances(x_o, ids)[1][..., 0])
        self.potential[ids] = self._potential(*self._distances(x_o, ids))

    # -- evaluation of the state --------------------------------------------------------
    def observe(self, ids: Any, team: Any) -> None:
        """The state metrics, from the kinematics kernel's team rows (T,) + B' of ``ids``."""
        xp = self.xp
        clearance = xp.where(self.has_obstacles[ids], team[CLEARANCE], np.inf)
        self.min_clearance[ids] = xp.minimum(self.min_clearance[ids], clearance)
        self.min_manipulability[ids] = xp.minimum(
            self.min_manipulability[ids], team[MANIPULABILITY]
        )
        self.grasp_drift[ids] = xp.maximum(self.grasp_drift[ids], team[GRASP_ERROR])

    def advance_robots(self, ids: Any, pose: Any, team: Any) -> bool:
        """Each robot's sequencer on its own object estimate ``pose`` B' + (N, 6): passes its
        waypoint within ``WAYPOINT_TOLERANCE``. False when no robot's waypoint changed
        (numpy: then ``robot_waypoint`` needs no copy into the kernel's inputs)."""
        xp = self.xp
        # the kernel's smallest squared distance: a cheap host test that no robot is near
        if self._host_tests and not self._any(
            team[WAYPOINT_DISTANCE2] < 1.01 * WAYPOINT_TOLERANCE**2
        ):
            return False
        index, done = self.robot_index[ids], self.robot_done[ids]
        d = pose[..., :3] - self.robot_waypoint[ids][..., :3]
        near = ~done & (xp.sqrt((d * d).sum(axis=-1)) < WAYPOINT_TOLERANCE)
        if self._host_tests and not near.any():  # B + (N,): an array even for B = ()
            return False
        last = index + 1 >= self.waypoint_count[ids][..., None]
        index = index + (near & ~last)
        self.robot_index[ids] = index
        self.robot_done[ids] = done | (near & last)
        self.robot_waypoint[ids] = self._waypoint_at(ids, index)
        return True

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
        x_o: Any,
        team: Any,
        constraint_values: Any,
        cost: Any,
        diverged: Any,
        sampled: Any = None,
        wrench_sq: Any = None,
        state: TaskArrays | None = None,
    ) -> StepOutcome:
        """The rules of one step of every environment, after ``tick`` and the evaluation:
        ``x_o`` B + (6,) the true object, ``team`` (T,) + B float64 the kernel's team rows,
        ``constraint_values`` B + (N, 8) and ``cost`` B + (N,) the kernel's, ``diverged`` B
        (bool) the refused steps, ``sampled``/``wrench_sq`` B the internal wrench samples
        (``tick``), ``state`` what the extensions see (needed when ``extended``)."""
        xp = self.xp
        kinds = team[KINDS].T > 0.0  # B + (8,)
        n_violated = team[VIOLATED]
        if self.constraint_fns:
            assert state is not None, "extra constraints need the state"
            extra = self.extra_constraint_values(state)
            violated = extra > 0.0
            constraint_values = xp.concatenate([constraint_values, extra], axis=-1)
            cost = cost + violated.sum(axis=-1)
            kinds = xp.concatenate([kinds, violated.any(axis=-2)], axis=-1)
            n_violated = n_violated + violated.sum(axis=(-2, -1))
        hard = kinds[..., self._hard]
        collision = hard.any(axis=-1) if self._hard_many else hard
        failed = diverged | collision
        if self.terminate:
            failed = failed | (n_violated > 0)
        d, dist = self._distances(x_o)
        success = self._success(d, dist, failed)
        terminated = success | failed
        truncated = (self.steps >= self.max_cycles) & ~terminated

        # metrics
        action_sq = team[ACTION_SQ]
        self.effort += action_sq * self.period
        self.violations += kinds
        if wrench_sq is not None:
            self.wrench_sq += wrench_sq
            self.wrench_samples += sampled

        terms = self._reward_terms(x_o, d, dist, success, failed, n_violated, action_sq, state)
        values = iter(terms.values())
        reward = next(values)
        for value in values:  # in order: REWARD_TERMS, then the extra terms
            reward = reward + value
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

    def _reward_terms(
        self,
        x_o: Any,
        d: Any,
        dist: Any,
        success: Any,
        failed: Any,
        n_violated: Any,
        action_sq: Any,
        state: TaskArrays | None,
    ) -> dict[str, Any]:
        """The shared reward's terms (``uvms_env.task.reward``), then the extra ones; moves
        the team's sequencer and the potential on."""
        xp, w = self.xp, self.weights
        # potential-based progress towards the team's waypoint
        potential = self._potential(d, dist)
        progress = w.progress * (self.potential - potential)
        passed = self._advance_team(ALL, dist[..., 0])
        if passed is not None:
            potential = xp.where(passed, self._potential(*self._distances(x_o)), potential)
            waypoint = passed * w.waypoint
        else:
            waypoint = xp.zeros(self.batch)
        self.potential[...] = potential
        terms = {
            "progress": progress,
            "waypoint": waypoint,
            "success": success * w.success,
            # 0.0 - ...: a clean 0.0 rather than -0.0 when nothing is violated
            "violation": 0.0 - self._per_violation * n_violated - failed * w.failure,
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

    def _distances(self, x_o: Any, ids: Any = ALL) -> tuple[Any, Any]:
        """Pose differences B' + (2, 6) of the true object ``x_o`` B' + (6,) to the team's
        active waypoint and to the goal, and their position distances B' + (2,)."""
        d = x_o[..., None, :] - self.targets[ids]
        p = d[..., :3]
        return d, self.xp.sqrt((p * p).sum(axis=-1))

    def _potential(self, d: Any, dist: Any) -> Any:
        """Phi = |p_O - p_wp| + w_attitude |wrap(Theta_O - Theta_wp)| (``_distances``)."""
        att = wrap_angle(d[..., 0, 3:], self.xp)
        return dist[..., 0] + self.weights.attitude * self.xp.sqrt((att * att).sum(axis=-1))

    def _advance_team(self, ids: Any, dist: Any) -> Any:
        """The team's sequencer passes its waypoint where the true object is within the
        tolerance (``dist`` to the active one); returns where an intermediate waypoint was
        passed, or None when (numpy, checked on the host) none was near."""
        near = dist < WAYPOINT_TOLERANCE
        if self._host_tests and not self._any(near):
            return None
        near = near & ~self.team_done[ids]
        index = self.team_index[ids]
        last = index + 1 >= self.waypoint_count[ids]
        passed = near & ~last
        self.team_index[ids] = index = index + passed
        self.team_done[ids] = self.team_done[ids] | (near & last)
        self.team_waypoint[ids] = self._waypoint_at(ids, index)
        return passed

    def _success(self, d: Any, dist: Any, failed: Any) -> Any:
        """Where the true object is at the goal (position and attitude tolerances) and the
        step did not fail (``_distances``)."""
        near = dist[..., 1] < self.pos_tol
        if self._host_tests and not self._any(near):  # the common case, decided cheaply
            return near
        att = self.xp.abs(wrap_angle(d[..., 1, 3:], self.xp)).max(axis=-1)
        return near & ~failed & (att < self.att_tol)

    # -- ended episodes ---------------------------------------------------------------------
    def results(self, ids: Any, x_o: Any, success: Any) -> list[dict[str, Any]]:
        """The metrics dicts of the episodes ``ids`` that ended at poses ``x_o`` B' + (6,)."""
        rows = [
            self._host(a)
            for a in (
                self.steps[ids],
                x_o,
                self.goal[ids],
                self.min_clearance[ids],
                self.min_manipulability[ids],
                self.violations[ids],
                self.wrench_sq[ids],
                self.wrench_samples[ids],
                self.effort[ids],
                self.grasp_drift[ids],
                success,
            )
        ]
        if not self.batch:  # one environment: a batch of one
            rows = [r[None] for r in rows]
        steps, pose, goal, clearance, manip, violations, wrench, samples, effort, drift, ok = rows
        return [
            episode_result(
                self.period,
                steps[j],
                pose[j].tolist(),
                goal[j].tolist(),
                bool(ok[j]),
                clearance[j],
                manip[j],
                violations[j].tolist(),
                wrench[j],
                samples[j],
                effort[j],
                drift[j],
                self.constraints,
            )
            for j in range(len(steps))
        ]

    def end_kinds(self, ids: Any, out: StepOutcome, diverged: Any) -> list[str]:
        """``episode_end`` of the environments ``ids``, from one host copy of the flags."""
        xp = self.xp
        flags = self._host(
            xp.stack([out.success[ids], diverged[ids], out.collision[ids], out.failed[ids]])
        ).reshape(4, -1)
        return [episode_end(*(bool(f) for f in col)) for col in flags.T.tolist()]

    def _host(self, a: Any) -> np.ndarray:
        return np.asarray(a) if self.xp is np else self.xp.asnumpy(a)


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
