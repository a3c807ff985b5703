"""The evaluation tool end to end on short episodes."""

from __future__ import annotations

import json
import re
from typing import ClassVar

import numpy as np

from baselines.evaluation.outputs import write_outputs
from baselines.evaluation.runner import evaluate
from uvms_env.task.rules import EPISODE_ENDS


class _Raises:
    def __init__(self, spec) -> None:
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs):
        raise RuntimeError("policy exploded")


def raising_factory(spec):
    return _Raises(spec)


def _strip(rows):
    # what differs between runs: the decision times and the episode's wall time
    measured = ("_", "policy_time", "wall_s")
    return [{k: v for k, v in r.items() if not k.startswith(measured)} for r in rows]


def _same(a: list[dict], b: list[dict]) -> bool:
    """Equal rows; floats to 1e-12 relative (NaN, a value an episode has none of, equal to
    NaN). Run inside the whole test suite (every test
    module imported, with its native libraries), the in-process episodes differed from
    the worker processes' by up to 3e-15 relative (the same episodes, not the same last
    bits); alone they are bit-identical."""
    if len(a) != len(b) or any(x.keys() != y.keys() for x, y in zip(a, b, strict=True)):
        return False
    for x, y in zip(a, b, strict=True):
        for key, u in x.items():
            v = y[key]
            if isinstance(u, float) and isinstance(v, float):
                if not np.isclose(u, v, rtol=1e-12, atol=1e-15, equal_nan=True):
                    return False
            elif u != v:
                return False
    return True


def test_deterministic_policy_gives_identical_results_with_1_and_2_workers():
    args = (["zero", "random"], ["short"], 2, 0)
    one = evaluate(*args, workers=1, max_cycles=15, progress=False)
    again = evaluate(*args, workers=1, max_cycles=15, progress=False)
    two = evaluate(*args, workers=2, max_cycles=15, progress=False)
    assert _same(_strip(one), _strip(again)) and _same(_strip(one), _strip(two))
    assert all(r["error"] == "" for r in one)
    assert {r["seed"] for r in one if r["policy"] == "zero"} == {
        r["seed"] for r in one if r["policy"] == "random"
    }


def test_a_raising_policy_is_a_failed_episode_not_a_crash(tmp_path):
    rows = evaluate(
        ["tests.evaluation.test_evaluate:raising_factory", "zero"],
        ["short"],
        1,
        0,
        workers=1,
        max_cycles=5,
        progress=False,
    )
    bad = [r for r in rows if r["policy"].startswith("tests.")]
    assert bad and "policy exploded" in bad[0]["error"] and bad[0]["success"] is False
    # how each ended: the raising policy's episode an error, the zero policy's at the limit
    assert [r["episode_end"] for r in rows] == ["error", "max_cycles"]
    summaries = write_outputs(rows, 0, tmp_path)
    assert (tmp_path / "episodes.csv").exists() and (tmp_path / "results.md").exists()
    assert json.loads((tmp_path / "results.json").read_text())[0]["errors"] == 1
    assert summaries[1]["errors"] == 0
    ends = [s["episode_ends"] for s in summaries]
    assert ends[0]["error"] == 1 and ends[1]["max_cycles"] == 1
    assert all(sum(e.values()) == s["episodes"] for e, s in zip(ends, summaries, strict=True))
    ends_table = (tmp_path / "results.md").read_text().split("| max_cycles | error |")[1]
    assert "| zero | short | 0 | 0 | 0 | 0 | 1 | 0 |" in ends_table


def test_random_policy_scores_lower_than_the_expert():
    rows = evaluate(["nmpc", "random"], ["short"], 2, 0, workers=2, progress=False)
    # each episode's recorded end is the env's, and it says success exactly when it succeeded
    assert all(r["episode_end"] in EPISODE_ENDS for r in rows)
    assert all((r["episode_end"] == "success") == bool(r["success"]) for r in rows)
    rate = {
        p: np.mean([bool(r["success"]) for r in rows if r["policy"] == p])
        for p in ("nmpc", "random")
    }
    assert rate["nmpc"] > rate["random"]


def test_replays_are_each_policys_first_episode_per_scenario(tmp_path):
    from uvms_env.replay import replay_path

    rows = evaluate(
        ["zero", "random"], ["short"], 2, 0, workers=1, max_cycles=4, progress=False,
        replay_dir=tmp_path,
    )  # fmt: skip
    assert all(r["error"] == "" for r in rows)
    pages = sorted(tmp_path.glob("replay_*.html"))
    assert pages == sorted(replay_path(tmp_path, p, "short") for p in ("zero", "random"))
    for page in pages:  # the episode's start and its 4 periods
        assert re.search(r'"episode_frames":\s*(\d+)', page.read_text()).group(1) == "5"


class _Recording:
    """An 8-number policy that notes the observations it is shown."""

    seen: ClassVar[list[int]] = []

    def __init__(self, spec) -> None:
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs):
        _Recording.seen.append(len(obs))
        return np.zeros(8, np.float32)


def test_existing_policies_play_silent_under_a_channel():
    """``--comm``: every policy that does not read messages plays unchanged, silent: it sees
    its observation without the inbox and its 8 numbers go out with send flag -1."""
    import uvms_env
    from uvms_env.episode import play

    rows = evaluate(["zero", "random", "nmpc:central"], ["paper"], 1, 0, 1, {"comm": "atm900"},
                    max_cycles=3, progress=False)  # fmt: skip
    assert [r["error"] for r in rows] == ["", "", ""]
    env = uvms_env.parallel_env("paper", comm="ideal", max_cycles=4)
    sent = []
    _Recording.seen = []
    play(env, _Recording, seed=0, on_step=lambda step: sent.append(step))
    assert set(_Recording.seen) == {79} and len(sent) == 4
    assert not env.observe()["uvms_0"][env.observation_structure["messages"]].any()
