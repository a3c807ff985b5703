"""The graded safety metrics: an ended episode's per-kind excess, largest excess and violated
share of robot-periods, their totals over the safety kinds and the clean successes, against
the same numbers computed by hand from the episode's per-step constraint values; the scales
from the limits' one source."""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from uvms_env.env.infos import constraint_values, episode_metrics
from uvms_env.models import load_parameters
from uvms_env.task.constraints import (
    CLEAN_TOLERANCE,
    CONSTRAINTS,
    MANIPULABILITY_EPS,
    REPRESENTATION_MARGIN,
    SAFETY_CONSTRAINTS,
    constraint_scales,
)
from uvms_env.task.metrics import metric_keys


def test_the_scales_are_the_limits():
    prm = load_parameters()
    lim = prm.limits
    scale = dict(zip(CONSTRAINTS, constraint_scales(prm), strict=True))
    assert scale["joint_speed"] == lim.joint_speed == 0.1  # a joint at 0.15 rad/s: 0.5
    assert scale["joint_limit"] == lim.joint_position
    assert scale["vehicle_speed"] == scale["input"] == 1.0  # already fractions of the limit
    assert scale["manipulability"] == MANIPULABILITY_EPS
    assert scale["representation"] == pytest.approx(np.pi / 2 - REPRESENTATION_MARGIN)
    assert scale["collision"] == scale["workspace"] == prm.vehicle.bounding_radius
    assert "input" not in SAFETY_CONSTRAINTS and len(SAFETY_CONSTRAINTS) == 7


def _episode(amplitude: float, steps: int, seed: int):
    """A ``short`` episode of random actions: each step's (N, C) constraint values and the
    last infos."""
    env = uvms_env.parallel_env("short", max_cycles=steps)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    g, infos = [], {}
    while env.agents:
        act = {a: amplitude * rng.uniform(-1.0, 1.0, 8) for a in env.agents}
        *_, infos = env.step(act)
        g.append([list(constraint_values(infos[a]).values()) for a in env.possible_agents])
    return np.array(g), infos[env.possible_agents[0]]


@pytest.mark.parametrize(("amplitude", "seed"), [(1.3, 4), (0.05, 2)])
def test_graded_metrics_are_the_hand_computed_sums_of_the_episodes_values(amplitude, seed):
    g, info = _episode(amplitude, 25, seed)
    metrics = episode_metrics(info)
    assert list(metrics) == list(metric_keys())
    periods, robots = g.shape[:2]
    scale = np.array(constraint_scales(load_parameters()))
    excess = np.maximum(g, 0.0) / scale  # (T, N, C)
    safe = np.array([k in SAFETY_CONSTRAINTS for k in CONSTRAINTS])
    for k, kind in enumerate(CONSTRAINTS):
        assert metrics[f"excess_{kind}"] == pytest.approx(excess[:, :, k].sum() / periods)
        assert metrics[f"max_excess_{kind}"] == pytest.approx(excess[:, :, k].max())
        share = (g[:, :, k] > 0).sum() / (periods * robots)
        assert metrics[f"violated_fraction_{kind}"] == pytest.approx(share)
        assert metrics[f"violations_{kind}"] == (g[:, :, k] > 0).any(axis=1).sum()
    assert metrics["excess"] == pytest.approx(excess[:, :, safe].sum() / periods)
    assert metrics["max_excess"] == pytest.approx(excess[:, :, safe].max())
    any_kind = (g[:, :, safe] > 0).any(axis=2)  # (T, N)
    assert metrics["violated_fraction"] == pytest.approx(any_kind.mean())
    counts = (g[:, :, safe] > 0).any(axis=1).sum(axis=0)  # periods per safety kind
    assert metrics["violation_periods"] == counts.sum()
    # the band: success is False here (25 periods), so both clean flags are too
    assert not metrics["success"] and not metrics["clean_success_tol"]
    if amplitude > 1.0:  # requests beyond the saturation: reported, left out of every total
        assert metrics["violations_input"] > 0 and metrics["max_excess_input"] > 0.2
        assert metrics["max_excess"] != pytest.approx(metrics["max_excess_input"])
    assert excess[:, :, safe].max() == 0.0 or metrics["excess"] > 0


def test_clean_success_within_the_band_reads_the_largest_excess():
    from uvms_env.task.metrics import EpisodeTallies, episode_result

    def result(largest: float, violated: int) -> dict:
        per_kind = np.zeros(len(CONSTRAINTS))
        k = CONSTRAINTS.index("joint_speed")
        per_kind[k] = largest
        tallies = EpisodeTallies(
            min_clearance=np.inf,
            min_manipulability=4.0,
            grasp_drift=0.0,
            effort=1.0,
            wrench_sq=0.0,
            wrench_samples=0,
            reward=3.0,
            any_violated=float(violated),
            violations=[0] * k + [violated] + [0] * (len(CONSTRAINTS) - k - 1),
            excess_sum=per_kind.tolist(),
            excess_max=per_kind.tolist(),
            violated_robots=(per_kind > 0).astype(float).tolist(),
        )
        return episode_result(0.12, 2, 10, [0.0] * 6, [0.0] * 6, True, tallies)

    small, large = result(0.5 * CLEAN_TOLERANCE, 1), result(2 * CLEAN_TOLERANCE, 1)
    assert small["success"] and not small["clean_success"] and small["clean_success_tol"]
    assert not large["clean_success_tol"]
    clean = result(0.0, 0)
    assert clean["clean_success"] and clean["clean_success_tol"]
    assert np.isnan(clean["min_obstacle_clearance_m"]) and np.isnan(clean["internal_wrench_rms"])
    assert clean["return"] == 3.0 and small["violated_fraction"] == pytest.approx(1 / 20)
