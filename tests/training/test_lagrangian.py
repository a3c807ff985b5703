"""The constraint cost and the Lagrange multiplier of constraint-aware training."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.lagrangian import (
    PERIOD_CAP,
    SCALES,
    CostSettings,
    Lagrangian,
    magnitude_cost,
    periods_left,
)
from baselines.rl.cost import CostPenalty
from uvms_env.models import load_parameters
from uvms_env.task.constraints import CONSTRAINTS


def test_magnitude_cost_is_the_normalized_excess():
    g = np.full(len(CONSTRAINTS), -0.3)
    assert magnitude_cost(g) == 0.0
    g[CONSTRAINTS.index("joint_speed")] = 0.05  # 0.15 rad/s against 0.1
    g[CONSTRAINTS.index("joint_limit")] = 0.2  # 2.2 rad against 2
    assert magnitude_cost(g) == pytest.approx(0.05 / 0.1 + 0.2 / 2.0)
    assert SCALES[CONSTRAINTS.index("joint_speed")] == load_parameters().limits.joint_speed
    g[CONSTRAINTS.index("joint_speed")] = 0.35  # 0.45 rad/s: a kind counts up to one limit
    assert magnitude_cost(g) == pytest.approx(1.0 + 0.2 / 2.0)
    g[CONSTRAINTS.index("input")] = 5.0  # clipped before the simulator: not a safety kind
    assert magnitude_cost(g) == pytest.approx(1.0 + 0.2 / 2.0)
    assert magnitude_cost(np.full(len(CONSTRAINTS), 9.0)) == PERIOD_CAP == 7


def test_a_failure_costs_the_rest_of_its_episode_at_the_cap():
    """Ending early never stops the cost: a robot whose episode diverged, collided or broke
    a constraint in terminate mode pays PERIOD_CAP for every period left to the limit; a
    success or a time-out pays nothing more."""
    from uvms_env.env.infos import end_code

    lag = Lagrangian(CostSettings("count"), robots=3)
    infos = [
        {"episode_end": end_code("diverged"), "episode_steps": 40, "max_cycles": 100},
        {"episode_end": end_code("success"), "episode_steps": 40, "max_cycles": 100},
        {"episode_end": 0},  # running
    ]
    left = [periods_left(i) for i in infos]
    assert left == [60, 0, 0]
    cost = lag.penalize(None, [2, 1, 0], np.array([True, True, False]), left)
    assert cost.tolist() == [2 + 60 * PERIOD_CAP, 1, 0]
    assert periods_left({"episode_end": end_code("collision"), "episode_steps": 9}, 10) == 1


def test_a_limit_per_period_compares_each_episodes_cost_over_its_periods():
    """With ``limit_per="period"`` an ended episode counts as its cost over the periods it
    covers (those it ran, and those a failure prices), so a long and a short episode that
    violate alike weigh alike; the dual step compares their mean with the limit, and the
    reported cost stays the mean per episode."""
    from uvms_env.env.infos import end_code

    settings = CostSettings("count", multiplier=1.0, cost_limit=0.25, lr=0.5, limit_per="period")
    lag = Lagrangian(settings, robots=2)
    per_episode = Lagrangian(CostSettings("count", multiplier=1.0, cost_limit=0.25, lr=0.5), 2)
    running = [{"episode_end": 0}] * 2
    for step in range(1, 5):  # robot 0: 4 periods at cost 1 then a time-out; robot 1 fails
        done = np.array([step == 4, step == 2])
        infos = list(running)
        if step == 2:
            infos[1] = {"episode_end": end_code("diverged"), "episode_steps": 2, "max_cycles": 6}
        left = [periods_left(i) for i in infos]
        for lg in (lag, per_episode):
            lg.penalize(None, [1, 3], done, left)
    # robot 1: 3 + 3 over 2 periods run, then 4 left at PERIOD_CAP: (6 + 4 * 7) / 6 periods
    robot1 = (6 + 4 * PERIOD_CAP) / 6
    totals = (4 + 6 + 4 * PERIOD_CAP) / 2  # what both report: the mean cost per episode
    assert lag.end_rollout() == per_episode.end_rollout() == pytest.approx(totals)
    assert lag.multiplier == pytest.approx(1.0 + 0.5 * ((4 / 4 + robot1) / 2 - 0.25))
    assert per_episode.multiplier == pytest.approx(1.0 + 0.5 * (totals - 0.25))


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="cost"):
        CostSettings(kind="area")
    with pytest.raises(ValueError, match="limit_per"):
        CostSettings(limit_per="step")
    with pytest.raises(ValueError, match="lr"):
        CostSettings(lr=-1.0)


def test_penalty_is_multiplier_times_each_robots_cost_and_the_dual_step_follows_it():
    """Two identical batched envs under the same actions: the wrapped one's reward is the
    other's minus lambda times each robot's magnitude cost; after the episodes end, one
    dual step moves lambda by lr (mean episode cost - limit)."""
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.sb3 import VectorVecEnv

    def make():
        return VectorVecEnv(VectorEnv("short", 2, dtype="float64", max_cycles=4), seed=7)

    settings = CostSettings("magnitude", multiplier=0.7, cost_limit=0.5, lr=0.2)
    wrapped, plain = CostPenalty(make(), settings), make()
    wrapped.reset()
    plain.reset()
    rng = np.random.default_rng(3)
    totals = np.zeros(4)
    for _ in range(4):
        actions = rng.uniform(-1, 1, (4, 8)).astype(np.float32)  # fast moves: violations
        wrapped.step_async(actions)
        plain.step_async(actions)
        _, r_w, done, infos = wrapped.step_wait()
        _, r_p, _, _ = plain.step_wait()
        g = plain.last_infos["constraint_values"].reshape(4, -1)
        cost = magnitude_cost(g)
        np.testing.assert_allclose(r_p - r_w, 0.7 * cost, rtol=1e-5, atol=1e-6)
        assert [i["constraint_cost"] for i in infos] == pytest.approx(cost)
        totals += cost
    assert done.all() and totals.max() > 0
    mean = wrapped.update_multiplier()
    assert mean == pytest.approx(totals.mean())
    assert wrapped.multiplier == pytest.approx(max(0.0, 0.7 + 0.2 * (totals.mean() - 0.5)))
    assert wrapped.update_multiplier() is None  # no episode ended since: no step
