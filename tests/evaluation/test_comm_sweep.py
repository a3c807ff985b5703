"""The communication sweep (``baselines.comm_sweep``): its grid, its pairing with the
silent expert and one tiny run end to end."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from baselines.comm_sweep import EXPERT, IDEAL, TALKER, grid, main, summarize
from baselines.ladder import CENTRAL


def test_grid_varies_the_preset() -> None:
    points = grid("atm900", (80.0, 2400.0), (0.0, 0.5), (0, 4))
    assert points[0].label == IDEAL and len(points) == 1 + 2 * 2 * 2
    p = next(p for p in points[1:] if (p.bit_rate, p.loss, p.latency) == (80.0, 0.5, 4))
    s = p.settings
    assert (s.bit_rate_bps, s.loss_probability, s.modem_latency_periods) == (80.0, 0.5, 4)
    assert s.message_dim == 4 and s.bits_per_value == 8  # the rest is the preset's
    with pytest.raises(ValueError, match="modem_latency_periods"):
        grid("atm900", (80.0,), (0.0,), (60,))  # beyond the inbox's age limit


def _row(policy: str, scenario: str, episode: int, steps: int, wrench: float) -> dict:
    return {
        "policy": policy,
        "scenario": scenario,
        "episode": episode,
        "success": True,
        "clean_success": True,
        "episode_steps": steps,
        "internal_wrench_rms": wrench,
        "control_effort": 1.0,
        "violation_periods": 0,
        "error": "",
    }


def test_ratios_pair_with_the_silent_expert() -> None:
    points = grid("atm900", (80.0,), (0.0,), (4,))
    talk = f"random N=2 | {points[1].label}"
    rows = [
        _row(EXPERT, "random N=2", 0, 100, 2.0),
        _row(EXPERT, "random N=2", 1, 200, 4.0),
        _row(TALKER, talk, 0, 90, 1.0),
        _row(TALKER, talk, 1, 180, 2.0),
    ]
    result = summarize(rows, ["random N=2"], points, seed=0)
    pooled = {e["run"]: e for e in result["pooled"]}
    mine = pooled[f"{TALKER} [{points[1].label}]"]
    assert mine["completion_periods_imputed_ratio"] == pytest.approx(0.9)
    assert mine["internal_wrench_rms_ratio"] == pytest.approx(0.5)
    assert pooled[EXPERT]["completion_periods_imputed_ratio"] == 1.0
    assert mine["bit_rate"] == 80.0 and mine["clean_success_rate"] == 1.0


def test_sweep_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    main(
        [
            "--n-agents",
            "2",
            "--no-paper",
            "--episodes",
            "1",
            "--max-cycles",
            "4",
            "--bit-rates",
            "80,inf",
            "--losses",
            "0.5",
            "--latencies",
            "1",
            "--workers",
            "1",
            "--out",
            str(out),
        ]
    )
    for name in ("sweep.md", "sweep.csv", "sweep.json", "comm_curve.png", "episodes.csv"):
        assert (out / name).exists(), name
    result = json.loads((out / "sweep.json").read_text())
    runs = {e["run"] for e in result["pooled"]}
    assert {EXPERT, CENTRAL, f"{TALKER} [{IDEAL}]"} <= runs and len(runs) == 5
    with open(out / "episodes.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 5 and not any(r["error"] for r in rows)
    assert len({r["seed"] for r in rows}) == 1  # every run plays the same episode
