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
