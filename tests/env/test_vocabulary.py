"""One vocabulary across the command lines: the episode length is ``max_cycles``, and the
expert's job writes the environment's metric names."""

from __future__ import annotations

import json

from uvms_env.task.metrics import METRICS


def test_the_experts_episode_length_is_max_cycles(tmp_path):
    from nmpc_expert.__main__ import main

    common = ["--scenario", "short", "--no-figures"]
    metrics = main([*common, "--max-cycles", "3", "--out", str(tmp_path / "run")])
    assert metrics["episode_steps"] == 3
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert set(METRICS) <= set(saved)
    assert saved["policy_time_ms_median"] > 0.0
