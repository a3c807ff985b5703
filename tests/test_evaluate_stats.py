"""Statistics and policy parsing of the evaluation tool (no environment needed)."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.evaluate import episode_seed
from baselines.policies import PolicySource
from baselines.stats import bootstrap_mean_interval, wilson_interval


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


def test_episode_seeds_are_shared_across_policies_and_distinct_across_episodes():
    seeds = {episode_seed(0, "paper", k) for k in range(100)}
    assert len(seeds) == 100
    assert episode_seed(0, "paper", 3) == episode_seed(0, "paper", 3)
    assert episode_seed(0, "paper", 3) != episode_seed(1, "paper", 3)


def test_policy_parsing():
    assert PolicySource.parse("random").name == "random"
    assert PolicySource.parse("nmpc:ipopt").arg == "ipopt"
    assert PolicySource.parse("mypkg.mymod:make").name == "module"
    with pytest.raises(ValueError, match="unknown policy"):
        PolicySource.parse("rnadom")


def test_episodes_beyond_the_currents_reach_are_left_out_of_the_rates():
    """An episode whose current the team cannot overcome is counted apart
    (``out_of_reach``), not as the policy's failure."""
    from baselines.evaluate import aggregate, markdown_table

    def row(k: int, success: bool, reach: bool) -> dict:
        return {
            "policy": "nmpc",
            "scenario": "paper",
            "episode": k,
            "error": "",
            "success": success,
            "clean_success": success,
            "current_within_reach": reach,
            "_decision_ms": [1.0],
        }

    rows = [row(0, True, True), row(1, False, True), row(2, False, False), row(3, True, True)]
    (s,) = aggregate(rows, seed=0)
    assert s["episodes"] == 4 and s["out_of_reach"] == 1
    assert s["success_rate"] == pytest.approx(2 / 3)
    assert s["clean_success_rate"] == pytest.approx(2 / 3)
    assert "current out of reach" in markdown_table([s])


def test_nmpc_policy_options():
    from baselines.policies import PolicySource

    assert PolicySource.parse("nmpc:paper").arg == "paper"
    with pytest.raises(ValueError, match="unknown nmpc option"):
        PolicySource.parse("nmpc:bogus").factory(0)


def test_within_reach_follows_the_current_preset():
    from baselines.evaluate import within_reach
    from uvms_env.scenarios import make

    assert within_reach(make("paper"))  # no current
    assert within_reach(make("paper", current="mild"))  # 0.1 m/s < 0.287 m/s
    assert not within_reach(make("paper", current="strong"))  # 0.3 m/s
