"""Minari datasets of ``python -m baselines.imitate collect``: where they live (a root of
their own, whatever else the parent folder holds), what they record (the environment's
spec, so ``recover_environment`` works)."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.imitation import dataset
from baselines.imitation.cli import main

pytest.importorskip("minari")

STEPS = 6
EXPERT = "experts.scripted:expert"  # cheap and deterministic, no NMPC


def _crowd(parent):
    """Folders Minari would misread as dataset ids if it scanned ``parent``."""
    (parent / "runs" / "dagger" / "data").mkdir(parents=True)
    (parent / "other").mkdir()
    (parent / "notes.txt").write_text("not a dataset")


def test_collect_next_to_other_folders_and_recover_environment(tmp_path):
    parent = tmp_path / "data"
    parent.mkdir()
    _crowd(parent)
    out = parent / "ds"
    args = ["collect", "--scenario", "short", "--episodes", "1", "--max-cycles", str(STEPS),
            "--expert", EXPERT, "--out", str(out)]  # fmt: skip
    main(args)
    main(args)  # writing again replaces it
    obs, act, episodes = dataset.read_dataset(parent, "ds")
    assert len(episodes) == 2 and obs.shape == (2 * STEPS, 79) and act.shape == (2 * STEPS, 8)

    data = dataset.load(out)
    assert data.total_episodes == 2
    kwargs = data.spec.env_spec.kwargs
    assert kwargs["scenario"] == "short" and kwargs["max_cycles"] == STEPS
    assert kwargs["internal_wrench_every"] == 0
    env = data.recover_environment()
    try:
        o, _ = env.reset(seed=0)  # as collect's episode 0 (--seed 0)
        # the centralized view: robot i's observation is the slice [79 i, 79 (i + 1))
        assert o.shape == (2 * 79,) and np.allclose(o[:79], episodes[0].observations[0])
        assert env.unwrapped.parallel.max_cycles == STEPS
    finally:
        env.close()
