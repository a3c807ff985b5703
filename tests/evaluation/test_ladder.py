"""The ladder command (``baselines.ladder``): its prices are the paired differences of
the evaluator's rows, and it runs end to end on a short case."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from scipy import stats

from baselines.evaluation.paired import significance_tests
from baselines.evaluation.runner import Case, case_episode_seed, evaluate
from baselines.evaluation.splits import DEV, TEST
from baselines.ladder import (
    BEYOND_TEAM_SIZES,
    PRICED,
    TALKER,
    TEAM_SIZES,
    add_case_arguments,
    cases,
    cases_of,
    ladder,
    main,
    price,
    settings_of,
    talks,
)
from uvms_env.scenarios.families import make
from uvms_env.scenarios.reach import current_within_reach


def _row(policy: str, episode: int, success: bool, steps: int, wrench: float, effort: float):
    return {
        "policy": policy,
        "information": "full" if policy == "nmpc:central" else "local",
        "scenario": "random N=3",
        "episode": episode,
        "success": success,
        "clean_success": success,
        "clean_success_tol": success,
        "episode_steps": steps,
        "max_cycles": 3000,
        "sim_time_s": 0.12 * steps,
        "internal_wrench_rms": wrench,
        "control_effort": effort,
        "excess": 0.0,
        "return": 10.0 * success,
        "violation_periods": 0,
        "current_within_reach": True,
        "error": "",
        "_decision_ms": [1.0, 2.0],
    }


def test_prices_are_paired_differences_over_every_episode_failures_at_the_cap():
    central = [(True, 500, 2.0, 100.0), (True, 600, 3.0, 120.0), (True, 700, 1.0, 90.0)]
    expert = [(True, 550, 4.0, 110.0), (False, 900, 9.0, 500.0), (True, 800, 2.0, 99.0)]
    rows = [_row("nmpc:central", k, *v) for k, v in enumerate(central)]
    rows += [_row("nmpc", k, *v) for k, v in enumerate(expert)]
    p = price(rows, "nmpc", "nmpc:central", "random N=3", seed=0)
    assert p["episodes"] == 3  # the failed episode is compared too, never left out
    assert p["success"]["difference"] == pytest.approx(-1 / 3)
    assert (p["success"]["a_only"], p["success"]["b_only"]) == (0, 1)
    time = p["completion periods"]
    # episode 1: the expert's failure after 900 periods counts at the cap, 3000
    assert time["difference"] == pytest.approx(((550 - 500) + (3000 - 600) + (800 - 700)) / 3)
    assert time["ratio"] == pytest.approx((550 + 3000 + 800) / (500 + 600 + 700))
    lo, hi = time["difference_ci95"]
    assert 50 <= lo <= hi <= 2400  # a bootstrap of the three paired differences
    assert p["internal wrench rms"]["ratio"] == pytest.approx((4 + 9 + 2) / (2 + 3 + 1))
    per_s = [e / (0.12 * n) for n, e in ((550, 110), (900, 500), (800, 99))]
    ref_s = [e / (0.12 * n) for n, e in ((500, 100), (600, 120), (700, 90))]
    effort = p["effort per second"]
    assert effort["difference"] == pytest.approx(np.mean(np.subtract(per_s, ref_s)))
    assert effort["p"] == pytest.approx(stats.wilcoxon(np.subtract(per_s, ref_s)).pvalue)
    result = ladder(rows, ["nmpc:central", "nmpc"], ["random N=3"], seed=0)
    expert_rung = next(s for s in result["rungs"] if s["policy"] == "nmpc")
    assert expert_rung["success"] == 2 and expert_rung["completion_periods"] == 675.0
    assert expert_rung["completion_periods_imputed"] == pytest.approx((550 + 3000 + 800) / 3)
    assert expert_rung["violation_periods"] == 0.0  # a zero is a value, not a gap
    for k, v in enumerate((0, 3, 900)):  # the median episode beside the run-away's mean
        rows[3 + k]["violation_periods"] = v
    spread = next(s for s in ladder(rows, ["nmpc"], ["random N=3"], 0)["rungs"])
    assert spread["violation_periods"] == 301.0 and spread["violation_periods_median"] == 3.0
    assert [q["rung"] for q in result["prices"]["decentralization"]] == ["nmpc"]
    assert result["prices"]["learning"] == []  # no learned rung here
    tests = [t for q in result["prices"]["decentralization"] for t in significance_tests(q)]
    assert all(t["p_holm"] >= t["p"] for t in tests)  # corrected within the table


def test_expert_variants_face_the_expert_and_learned_rungs_their_prior():
    """An ablation's rows (other distributed experts) are priced against ``nmpc``; each
    learned rung also against ``prior``, its zero residual; the trivial rungs are no
    learned rung."""
    policies = ["nmpc", "nmpc:paper", "ppo:run", "prior", "zero", "random"]
    rows = [_row(p, k, k % 2 == 0, 600 + k, 1.0, 50.0) for p in policies for k in range(3)]
    prices = ladder(rows, policies, ["random N=3"], seed=0)["prices"]
    pairs = {kind: {(q["rung"], q["reference"]) for q in qs} for kind, qs in prices.items()}
    assert pairs["the expert's variants"] == {("nmpc:paper", "nmpc")}
    assert pairs["learning against the prior"] == {("ppo:run", "prior")}
    assert ("prior", "nmpc") in pairs["learning"] and ("ppo:run", "nmpc") in pairs["learning"]
    assert pairs["decentralization"] == set()  # no full-information rung played
    without_prior = ladder(rows, ["nmpc", "ppo:run"], ["random N=3"], seed=0)["prices"]
    assert without_prior["learning against the prior"] == []


def test_a_case_plays_the_episodes_of_the_plain_evaluator_command():
    """``Case("random N=3", "random", n_agents=3)`` gives the rows of
    ``--scenario random --n-agents 3``: the same seeds and the same episode."""
    (case,) = cases((3,), paper=False, bars=False)
    assert case == Case("random N=3", "random", (("n_agents", 3),))
    kw = dict(workers=1, max_cycles=3, progress=False)
    labelled = evaluate(["zero"], [case], 1, 5, overrides={"current": "mild"}, **kw)
    plain = evaluate(["zero"], ["random"], 1, 5, overrides={"current": "mild", "n_agents": 3}, **kw)
    assert labelled[0]["scenario"] == "random N=3" and plain[0]["scenario"] == "random"
    assert labelled[0]["seed"] == plain[0]["seed"] == case_episode_seed(5, "random", 0)
    for key in ("control_effort", "internal_wrench_rms", "final_pos_error_m"):
        assert labelled[0][key] == plain[0][key]
    with pytest.raises(ValueError, match="label"):
        evaluate(["zero"], [case, case], 1, 5, **kw)


def test_the_ladder_command_runs_end_to_end(tmp_path):
    main(
        [
            "--policy", "nmpc:central", "--policy", "nmpc", "--policy", "zero",
            "--policy", "prior", "--n-agents", "2", "--episodes", "1", "--split", "dev",
            "--workers", "1", "--max-cycles", "8", "--out", str(tmp_path),
        ]
    )  # fmt: skip
    result = json.loads((tmp_path / "ladder.json").read_text())
    labels = {(s["policy"], s["scenario"]) for s in result["rungs"]}
    assert labels == {
        (p, c)
        for p in ("nmpc:central", "nmpc", "zero", "prior")
        for c in ("random N=2", "random bar N=2", "paper")
    }
    assert all(s["errors"] == 0 for s in result["rungs"])
    central = next(s for s in result["rungs"] if s["policy"] == "nmpc:central")
    assert central["information"] == "full"
    assert {q["rung"] for q in result["prices"]["decentralization"]} == {"nmpc"}
    assert {q["rung"] for q in result["prices"]["learning"]} == {"zero", "prior"}
    assert all(set(PRICED) <= set(q) for q in result["prices"]["learning"])
    reference = result["prices"]["learning against the reference"]
    assert {(q["rung"], q["reference"]) for q in reference} == {
        ("zero", "nmpc:central"),
        ("prior", "nmpc:central"),
    }
    assert result["command"]["conditions"] == {"current": "mild", "mismatch": 0.1}
    assert result["command"]["split"] == {"name": "dev", "version": DEV.version, "beyond": False}
    assert result["command"]["seed"] == DEV.seed
    pooled = {(s["policy"], s["scenario"]) for s in result["pooled"]}
    assert ("nmpc", "rings") in pooled and ("nmpc", "all") in pooled
    names = ("ladder.md", "ladder_clean_success_vs_n.png", "episodes.csv", "results.md")
    for name in names:
        assert (tmp_path / name).stat().st_size > 0
    text = (tmp_path / "ladder.md").read_text()
    assert "Price of decentralization" in text and "Main table" in text and "CPU-hours" in text
    assert "| `nmpc:central` | full |  | 0/1 [0.00, 0.79] | 0/1 [0.00, 0.79] |" in text
    assert np.isfinite(central["decision_ms_median"])


def test_the_talking_expert_plays_the_same_episodes_over_the_channel(tmp_path):
    """``nmpc:comm`` is a rung: it plays each case's episodes (the same seeds) over the
    ``--comm`` channel while the silent rungs play without one; a talking variant is
    recognized by its option, nothing else is."""
    assert TALKER == "nmpc:comm" and talks("nmpc:comm,q_v=0.3")
    assert not any(talks(p) for p in ("nmpc", "nmpc:paper", "nmpc:central", "ppo:comm"))
    main(
        [
            "--policy", "nmpc", "--policy", TALKER, "--n-agents", "2", "--no-bars",
            "--no-paper", "--episodes", "1", "--split", "dev", "--workers", "1",
            "--max-cycles", "6", "--comm", "ideal", "--out", str(tmp_path),
        ]
    )  # fmt: skip
    result = json.loads((tmp_path / "ladder.json").read_text())
    assert result["command"]["talking_channel"] == "ideal"
    assert all(s["errors"] == 0 for s in result["rungs"])
    rows = (tmp_path / "episodes.csv").read_text().splitlines()
    head = rows[0].split(",")
    seeds = {r.split(",")[head.index("policy")]: r.split(",")[head.index("seed")] for r in rows[1:]}
    assert set(seeds) == {"nmpc", TALKER} and seeds["nmpc"] == seeds[TALKER]
    assert {q["rung"] for q in result["prices"]["the expert's variants"]} == {TALKER}


def test_an_unknown_channel_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--comm", "nonsense", "--out", "/nonexistent/ladder"])
    assert exit_info.value.code == 2
    assert "--comm" in capsys.readouterr().err


def test_split_and_seed_exclude_each_other_before_any_work(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--split", "test", "--seed", "3", "--out", "/nonexistent/ladder"])
    assert exit_info.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def _ladder_args(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    add_case_arguments(ap, TEAM_SIZES, "runs/ladder")
    return ap.parse_args(argv)


def test_beyond_plays_the_largest_teams_at_the_splits_counts_for_them():
    """``--beyond``: rings and bars of 7 and 8 robots, no ``paper``, each kind of rung at
    the split's ``beyond`` count; without it the ladder's own cases and counts."""
    assert set(BEYOND_TEAM_SIZES).isdisjoint(TEAM_SIZES)
    args = _ladder_args("--beyond", "--split", "test")
    labels = [c.label for c in cases_of(args)]
    assert labels == ["random N=7", "random N=8", "random bar N=7", "random bar N=8"]
    settings = settings_of(args)
    counts = [settings.episodes_of(p) for p in ("dagger:mix", "nmpc:paper", "nmpc:central")]
    assert counts == list(TEST.beyond) and TEST.beyond != (TEST.fast, TEST.model, TEST.central)
    assert settings.record()["split"] == {"name": "test", "version": TEST.version, "beyond": True}
    plain = _ladder_args("--split", "test")
    assert [c.label for c in cases_of(plain)][-1] == "paper" and len(cases_of(plain)) == 11
    assert settings_of(plain).episodes_of("dagger:mix") == TEST.fast
    only_bars = _ladder_args("--beyond", "--no-rings", "--n-agents", "8")
    assert [c.label for c in cases_of(only_bars)] == ["random bar N=8"]


def test_beyond_refuses_a_training_team_size_before_any_work(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--beyond", "--n-agents", "6", "--out", "/nonexistent/ladder"])
    assert exit_info.value.code == 2
    assert "--beyond" in capsys.readouterr().err


@pytest.mark.parametrize("shape", ["ring", "bar"])
def test_the_beyond_cases_are_seeded_and_within_reach(shape):
    """Each beyond case's first test episodes: the same geometry from the same seed, a
    team the random family draws at that size, and the ladder's mild current within its
    reach (every episode counts in the tables)."""
    for n in BEYOND_TEAM_SIZES:
        for k in range(3):
            seed = case_episode_seed(TEST.seed, "random", k)
            kw = dict(seed=seed, n_agents=n, object=shape, course="mixed", current="mild")
            a, b = make("random", **kw), make("random", **kw)
            assert a.n_agents == n and np.array_equal(a.waypoints, b.waypoints)
            assert np.array_equal(a.grasp_offsets, b.grasp_offsets)
            within, current, top = current_within_reach(a)
            assert within and current < top


def test_runs_apart_merge_into_the_ladder_of_one_run(tmp_path):
    """``--from``: rungs evaluated apart on the same seed give, read back from their
    episodes.csv, the rung summaries of one run with all of them (each rung plays the
    same seeded episodes whatever runs beside it); decision times then come from the
    episodes' own medians."""
    common = ["--n-agents", "2", "--no-paper", "--episodes", "2", "--seed", "4",
              "--workers", "1", "--max-cycles", "8"]  # fmt: skip
    main(["--policy", "zero", "--policy", "random", *common, "--out", str(tmp_path / "both")])
    main(["--policy", "zero", *common, "--out", str(tmp_path / "a")])
    main(["--policy", "random", *common, "--out", str(tmp_path / "b")])
    sources = ["--from", str(tmp_path / "a" / "episodes.csv")]
    sources += ["--from", str(tmp_path / "b" / "episodes.csv")]
    main([*sources, "--seed", "4", "--out", str(tmp_path / "m")])
    one = json.loads((tmp_path / "both" / "ladder.json").read_text())["rungs"]
    merged = json.loads((tmp_path / "m" / "ladder.json").read_text())["rungs"]
    assert [(s["policy"], s["scenario"]) for s in merged] == [
        (s["policy"], s["scenario"]) for s in one
    ]
    timing = ("decision_ms_median", "decision_ms_p95", "wall_s")
    for a, b in zip(one, merged, strict=True):
        assert set(a) == set(b)
        for key in set(a) - set(timing):
            if isinstance(a[key], str | dict) or a[key] is None:  # dict: the episodes' ends
                assert a[key] == b[key], key
            else:  # CSV keeps every digit of a float: the same numbers
                np.testing.assert_allclose(a[key], b[key], rtol=1e-12, err_msg=key)
        assert b["decision_ms_median"] > 0
