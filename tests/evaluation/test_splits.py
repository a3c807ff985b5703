"""The evaluation's splits: ``test``'s episodes are none that the repository used before it
was frozen (no named seed, no episode of a named seed's evaluations, no training pool's
geometry), ``dev`` is today's seed-202 episodes, and each kind of rung plays its count."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from baselines.evaluation.runner import Settings, case_episode_seed
from baselines.evaluation.splits import DEV, SPLITS, TEST, kind_of

ROOT = Path(__file__).resolve().parents[2]
NAMED = ROOT / "tests" / "golden" / "seeds_named_3361969.txt"
SCENARIOS = ("random", "paper", "short")
POOLS = 10**6  # geometry pools, CLI and training seeds all lie below this


def _named() -> list[int]:
    return [int(x) for x in NAMED.read_text().split() if x.isdigit()]


def test_the_test_episodes_were_used_nowhere_before():
    named = _named()
    assert len(named) > 40 and 202 in named and TEST.seed not in named
    before = {case_episode_seed(s, sc, k) for s in named for sc in SCENARIOS for k in range(1000)}
    mine = {case_episode_seed(TEST.seed, sc, k) for sc in SCENARIOS for k in range(TEST.fast)}
    assert len(mine) == len(SCENARIOS) * TEST.fast  # no two of its episodes alike
    assert not mine & before
    assert not mine & set(named)
    assert min(mine) >= POOLS


def test_no_committed_model_was_trained_or_selected_with_a_test_seed():
    episodes = {case_episode_seed(TEST.seed, sc, k) for sc in SCENARIOS for k in range(50)}
    mine = {TEST.seed} | episodes
    cards = list((ROOT / "baselines" / "pretrained").glob("*/*.json"))
    assert len(cards) >= 8
    for card in cards:  # every integer a card or a run's config.json names
        assert not {int(w) for w in re.findall(r"\d+", card.read_text())} & mine, card


def test_dev_is_seed_202_and_the_counts_follow_the_kind_of_rung():
    assert DEV.seed == 202 and SPLITS == {"dev": DEV, "test": TEST}
    assert (TEST.fast, TEST.model, TEST.central) == (50, 20, 10)
    assert kind_of("nmpc:central") == "central"
    assert kind_of("nmpc") == kind_of("nmpc:paper") == kind_of("dagger:mix+filter") == "model"
    assert kind_of("dagger:mix") == kind_of("prior") == kind_of("random") == "fast"
    settings = Settings(None, TEST.seed, 1, split="test")
    assert [settings.episodes_of(p) for p in ("ppo:scratch", "nmpc", "nmpc:central")] == [
        50,
        20,
        10,
    ]
    assert Settings(3, TEST.seed, 1, split="test").episodes_of("nmpc") == 3  # --episodes wins
    # beyond the training conditions: fewer episodes per case, in the same order of kinds
    assert TEST.beyond == (20, 10, 5) and DEV.beyond == (10, 10, 10)
    beyond = Settings(None, TEST.seed, 1, split="test", beyond=True)
    assert [beyond.episodes_of(p) for p in ("prior", "nmpc:comm", "nmpc:central")] == [20, 10, 5]
    with pytest.raises(ValueError, match="seed"):
        Settings(None, 5, 1, split="test")
