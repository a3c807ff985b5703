"""Statistics and policy parsing of the evaluation tool (no environment needed)."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.evaluation.runner import case_episode_seed
from baselines.loaders.sources import PolicySource
from baselines.stats import (
    bootstrap_mean_interval,
    holm,
    mcnemar_exact,
    wilcoxon_paired,
    wilson_interval,
)


def test_wilson_interval_agrees_with_scipy():
    from scipy.stats import binomtest

    for k, n in [(0, 10), (10, 10), (5, 10), (17, 20), (1, 3)]:
        ref = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        assert wilson_interval(k, n) == pytest.approx((ref.low, ref.high), abs=1e-9)


def test_bootstrap_interval_brackets_the_mean_and_is_reproducible():
    x = np.random.default_rng(0).normal(3.0, 1.0, 50)
    lo, hi = bootstrap_mean_interval(x, seed=1)
    assert lo < x.mean() < hi
    assert (lo, hi) == bootstrap_mean_interval(x, seed=1)
    assert hi - lo == pytest.approx(2 * 1.96 / np.sqrt(50), rel=0.25)


def test_exact_mcnemar_is_the_binomial_tail_of_the_discordant_pairs():
    from math import comb

    a = [1, 1, 1, 0, 1, 1, 0, 1, 1, 1, 0, 1]
    b = [0, 0, 1, 0, 0, 1, 1, 0, 1, 0, 0, 1]
    test = mcnemar_exact(a, b)
    only_a, only_b = 5, 1  # episodes won by one of the two
    assert (test["a_only"], test["b_only"]) == (only_a, only_b)
    n = only_a + only_b
    tail = sum(comb(n, i) for i in range(min(only_a, only_b) + 1)) / 2**n
    assert test["p"] == pytest.approx(min(1.0, 2 * tail))  # 2 * 7 / 64
    assert mcnemar_exact([1, 0, 1], [1, 0, 1])["p"] == 1.0  # no discordant pair
    with pytest.raises(ValueError, match="length"):
        mcnemar_exact([1, 0], [1])


def test_wilcoxon_matches_the_exact_signed_rank_distribution():
    from itertools import product

    x = np.array([3.1, 2.0, 5.5, 4.0, 1.2, 6.3, np.nan])
    y = np.array([2.0, 2.6, 3.0, 1.4, 1.0, 2.1, 9.0])
    test = wilcoxon_paired(x, y)
    d = (x - y)[:6]  # the NaN pair is dropped
    ranks = np.argsort(np.argsort(np.abs(d))) + 1.0  # no ties here
    w = ranks[d > 0].sum()
    # every sign pattern is equally likely under the null: enumerate them
    sums = [
        sum(r for r, s in zip(ranks, signs, strict=True) if s)
        for signs in product((0, 1), repeat=6)
    ]
    centre = ranks.sum() / 2
    p = np.mean([abs(t - centre) >= abs(w - centre) for t in sums])
    assert test["pairs"] == 6 and test["p"] == pytest.approx(p)
    assert test["median_difference"] == pytest.approx(np.median(d))
    assert wilcoxon_paired([1.0, 2.0], [1.0, 2.0])["p"] == 1.0  # every difference zero


def test_holm_adjusts_by_rank_and_keeps_the_order():
    p = [0.01, 0.04, 0.03, 0.005, float("nan")]
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 -> 0.02, 0.03, 0.06, 0.04 -> monotone
    expected = [0.03, 0.06, 0.06, 0.02]
    assert holm(p)[:4] == pytest.approx(expected) and np.isnan(holm(p)[4])
    assert holm([0.6, 0.5]) == [1.0, 1.0]


def test_episode_seeds_are_shared_across_policies_and_distinct_across_episodes():
    seeds = {case_episode_seed(0, "paper", k) for k in range(100)}
    assert len(seeds) == 100
    assert case_episode_seed(0, "paper", 3) == case_episode_seed(0, "paper", 3)
    assert case_episode_seed(0, "paper", 3) != case_episode_seed(1, "paper", 3)


def test_policy_parsing():
    assert PolicySource.parse("random").name == "random"
    assert PolicySource.parse("nmpc:ipopt").arg == "ipopt"
    assert PolicySource.parse("mypkg.mymod:make").name == "module"
    with pytest.raises(ValueError, match="unknown policy"):
        PolicySource.parse("rnadom")


def _row(k: int, success: bool, **more) -> dict:
    """Episode ``k`` of ``nmpc`` on ``paper``, a clean success or a failure."""
    return {
        "policy": "nmpc",
        "scenario": "paper",
        "episode": k,
        "error": "",
        "success": success,
        "clean_success": success,
        "_decision_ms": [1.0],
        **more,
    }


def test_episodes_beyond_the_currents_reach_are_left_out_of_the_rates():
    """An episode whose current the team cannot overcome is counted apart
    (``out_of_reach``), not as the policy's failure."""
    from baselines.evaluation.report import markdown_table
    from baselines.evaluation.summary import aggregate

    reach = [True, True, False, True]
    rows = [_row(k, k in (0, 3), current_within_reach=r) for k, r in enumerate(reach)]
    (s,) = aggregate(rows, seed=0)
    assert s["episodes"] == 4 and s["out_of_reach"] == 1
    assert s["success_rate"] == pytest.approx(2 / 3)
    assert s["clean_success_rate"] == pytest.approx(2 / 3)
    assert "current out of reach" in markdown_table([s])


def test_nmpc_policy_options():
    from baselines.loaders.sources import PolicySource

    assert PolicySource.parse("nmpc:paper").arg == "paper"
    with pytest.raises(ValueError, match="unknown nmpc option"):
        PolicySource.parse("nmpc:bogus").factory(0)
    with pytest.raises(ValueError, match="unknown NMPC setting"):
        PolicySource.parse("nmpc:no_such_setting=1").factory(0)


def test_nmpc_settings_from_the_policy_name():
    """``nmpc:NAME=VALUE`` reaches the controller's settings; the rest stay the defaults."""
    from baselines.loaders.sources import PolicySource
    from nmpc_expert import NMPCSettings
    from uvms_env.policy import AgentSpec
    from uvms_env.scenarios import make

    spec = AgentSpec.from_scenario(make("short"), 0)
    policy = PolicySource.parse("nmpc:paper,goal_integral_angle_limit=0.3,q_v=0.5").factory(0)(spec)
    expected = NMPCSettings.paper(goal_integral_angle_limit=0.3, q_v=0.5)
    assert policy.settings == expected
    # a tuple VALUE keeps its commas: the options split outside brackets only
    name = "nmpc:vehicle_speed_fraction=(0.9, 0.8),rti,piece_fraction=0.5"
    policy = PolicySource.parse(name).factory(0)(spec)
    assert policy.settings == NMPCSettings(vehicle_speed_fraction=(0.9, 0.8), piece_fraction=0.5)
    assert PolicySource.parse("nmpc").factory(0)(spec).settings == NMPCSettings()


def test_within_reach_follows_the_current_preset():
    from baselines.evaluation.episode_row import within_reach
    from uvms_env.scenarios import make

    assert within_reach(make("paper"))  # no current
    assert within_reach(make("paper", current="mild"))  # 0.1 m/s < 0.287 m/s
    assert not within_reach(make("paper", current="strong"))  # 0.3 m/s


def test_the_evaluator_and_the_ladder_read_one_summary():
    """``aggregate`` (results.json) and the ladder's rungs are views of one
    ``summarize``: the same numbers where they report the same thing, and rows read back
    from episodes.csv (no per-decision times) fall back on the episodes' own medians."""
    from baselines.evaluation.summary import aggregate, decision_times
    from baselines.ladder import rung_summary

    rows = [
        _row(k, k != 2, internal_wrench_rms=1.0 + k, control_effort=10.0 * k,
             violation_periods=k, _decision_ms=[1.0 + k, 2.0])
        for k in range(5)
    ]  # fmt: skip
    (table,) = aggregate(rows, seed=0)
    rung = rung_summary(rows, seed=0)
    for key in ("episodes", "out_of_reach", "errors", "success_rate", "success_ci95",
                "clean_success_rate", "clean_success_ci95", "internal_wrench_rms",
                "internal_wrench_rms_ci95", "clean_success_tol_rate"):  # fmt: skip
        assert table[key] == rung[key], key
    assert rung["decision_ms_median"] == table["policy_time_ms"]["median"] == 2.0
    assert rung["completion_periods"] is None  # no episode_steps: nothing to average
    csv_rows = [
        {"policy_time_ms_median": m, "policy_time_ms_p95": 2 * m, "policy_time_ms_max": 3 * m}
        for m in (1.0, 2.0, 4.0)
    ]
    assert decision_times(csv_rows) == {"median": 2.0, "p95": 4.0, "max": 12.0}
