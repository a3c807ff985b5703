"""One vocabulary across the command lines: the episode length is ``max_cycles`` (the
expert's ``--max-steps`` a deprecated alias), the features observation mode is
``features`` (the imitation CLI's ``uvms-v2`` a deprecated alias)."""

from __future__ import annotations

import json

import pytest


def test_the_experts_episode_length_is_max_cycles_and_max_steps_still_works(tmp_path):
    from nmpc_expert.__main__ import main

    common = ["--scenario", "short", "--no-figures"]
    metrics = main([*common, "--max-cycles", "3", "--out", str(tmp_path / "new")])
    assert metrics["episode_steps"] == 3
    with pytest.warns(FutureWarning, match="--max-steps is deprecated.*--max-cycles"):
        old = main([*common, "--max-steps", "3", "--out", str(tmp_path / "old")])
    assert old["episode_steps"] == 3
    saved = json.loads((tmp_path / "old" / "metrics.json").read_text())
    assert saved["final_pos_error_m"] == metrics["final_pos_error_m"]  # the same episode


def test_the_imitation_cli_reads_the_earlier_feature_name_as_features():
    from baselines.imitation.cli import _features

    assert _features("features") == "features"
    with pytest.warns(FutureWarning, match="--features uvms-v2 is deprecated"):
        assert _features("uvms-v2") == "features"
