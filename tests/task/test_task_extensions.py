"""A user's own reward term and constraint, supplied without touching the package, apply
to the single env, the vector env (CPU and the CUDA backend's kernels on the host) and
the evaluator alike: they take effect (checked against the true state) and the single
and vector envs agree on them to 1e-9, episode ends and automatic resets included."""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from baselines.evaluation.runner import case_episode_seed, evaluate
from uvms_env.env.infos import constraint_values, end_name, episode_metrics, reward_terms
from uvms_env.vector import VectorEnv

TOL = 1e-9
SLOW = 0.03  # rad/s: tighter than the built-in joint_speed limit (0.1)


def tilt(s, xp):
    """Reward term: the object's roll and pitch cost reward."""
    return -0.5 * (xp.abs(s.object_pose[:, 3]) + xp.abs(s.object_pose[:, 4]))


def slow_joints(s, xp):
    """Constraint: every joint rate within SLOW (g <= 0 holds), per robot."""
    return xp.abs(s.zeta[:, :, 6:]).max(axis=2) - SLOW


EXTENSIONS = {
    "extra_reward_terms": {"tilt": tilt},
    "extra_constraints": {"slow_joints": slow_joints},
}


def _actions(seed: int, steps: int, k: int, n: int = 2) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.4, 0.4, (steps, k, n, 8))


def test_single_env_applies_them_to_the_true_state():
    """By name as ``module:function`` too; against the same episode without them."""
    me = f"{__name__}:"
    ext = uvms_env.parallel_env(
        "short",
        extra_reward_terms={"tilt": me + "tilt"},
        extra_constraints={"slow_joints": me + "slow_joints"},
        max_cycles=25,
    )
    plain = uvms_env.parallel_env("short", max_cycles=25)
    agents = ext.possible_agents
    ext.reset(seed=3)
    plain.reset(seed=3)
    periods = all_kinds = 0
    for act in _actions(3, 25, 1)[:, 0]:
        actions = {a: act[i] for i, a in enumerate(agents)}
        _, r, _, tr, info = ext.step(actions)
        _, r0, _, _, info0 = plain.step(actions)
        st = ext.sim.state
        g = np.abs(st.zeta[:, 6:]).max(axis=1) - SLOW
        terms, terms0 = reward_terms(info[agents[0]]), reward_terms(info0[agents[0]])
        assert terms["tilt"] == pytest.approx(-0.5 * np.abs(st.x_O[3:5]).sum(), abs=TOL)
        violated = g > 0
        periods += bool(violated.any())
        kinds = [k for k in constraint_values(info[agents[0]]) if k != "input"]  # the counted
        all_kinds += sum(any(info[a][f"constraint_{k}"] > 0 for a in agents) for k in kinds)
        extra_violation = -ext.reward_weights.violation * violated.sum() / len(agents)
        assert terms["violation"] == pytest.approx(terms0["violation"] + extra_violation, abs=TOL)
        assert r[agents[0]] == pytest.approx(r0[agents[0]] + terms["tilt"] + extra_violation)
        for i, a in enumerate(agents):
            assert info[a]["constraint_slow_joints"] == pytest.approx(g[i], abs=TOL)
            assert info[a]["cost"] == info0[a]["cost"] + violated[i]
    assert tr[agents[0]]
    metrics = episode_metrics(info[agents[0]])
    assert metrics["violations_slow_joints"] == periods > 0  # the test can fail
    # every safety kind's periods, built-in and extra
    assert metrics["violation_periods"] == all_kinds >= periods
    assert metrics["clean_success"] is False
    assert ext.constraint_values()[agents[0]].keys() == constraint_values(info[agents[0]]).keys()


def test_terminate_mode_ends_the_episode_on_an_extra_constraint():
    env = uvms_env.parallel_env("short", constraint_mode="terminate", **EXTENSIONS)
    env.reset(seed=3)
    agents = env.possible_agents
    for t, act in enumerate(_actions(3, 40, 1)[:, 0]):
        _, _, te, _, info = env.step({a: act[i] for i, a in enumerate(agents)})
        slow = [info[a]["constraint_slow_joints"] for a in agents]
        if te[agents[0]]:
            assert end_name(info[agents[0]]) == "constraint"
            assert max(slow) > 0 and info[agents[0]]["violations_slow_joints"] == 1
            break
        assert max(slow) <= 0, t
    else:
        pytest.fail("no episode end")


@pytest.mark.parametrize("backend", ["cpu", "cuda"])
def test_vector_env_agrees_with_single_envs(backend):
    """K = 2 against two single envs through episode ends and automatic resets."""
    k, steps = 2, 16
    kw = {"backend": backend, "device": "cpu"} if backend == "cuda" else {}
    venv = VectorEnv("short", k, threads=2, max_cycles=7, **kw, **EXTENSIONS)
    singles = [uvms_env.parallel_env("short", max_cycles=7, **EXTENSIONS) for _ in range(k)]
    agents = singles[0].possible_agents
    venv.reset(seed=5)
    for i, env in enumerate(singles):
        env.reset(seed=5 + i)
    host = lambda x: np.asarray(x.cpu() if hasattr(x, "cpu") else x, float)  # noqa: E731
    ends = 0
    for t, act in enumerate(_actions(5, steps, k)):
        _, reward, _, _, infos = venv.step(act)
        names = list(infos["reward_terms"])
        assert names[-1] == "tilt"
        for i, env in enumerate(singles):
            _, r, te, tr, info = env.step({a: act[i, j] for j, a in enumerate(agents)})
            head = info[agents[0]]
            assert host(reward)[i] == pytest.approx(r[agents[0]], abs=TOL), t
            for name in names:
                assert host(infos["reward_terms"][name])[i] == pytest.approx(
                    head[f"reward_{name}"], abs=TOL
                ), (name, t)
            g = [list(constraint_values(info[a]).values()) for a in agents]
            np.testing.assert_allclose(host(infos["constraint_values"])[i], g, atol=TOL)
            np.testing.assert_array_equal(host(infos["cost"])[i], [info[a]["cost"] for a in agents])
            if te[agents[0]] or tr[agents[0]]:
                ends += 1
                mine, theirs = infos["metrics"][i], episode_metrics(head)
                assert list(mine) == list(theirs)
                for key in mine:
                    if key.startswith(("violations_", "violated_fraction", "violation_periods")):
                        assert mine[key] == theirs[key], key
                    elif key.startswith(("excess", "max_excess")):
                        assert mine[key] == pytest.approx(theirs[key], abs=1e-6), key
                assert mine["clean_success"] == theirs["clean_success"]
                assert "violations_slow_joints" in mine
                assert mine["control_effort"] == pytest.approx(theirs["control_effort"], abs=TOL)
                env.reset()
    assert ends >= 2


def test_evaluator_passes_them_to_its_environments():
    """The evaluator's episode is the single env's with the extensions (same seed)."""
    rows = evaluate(["zero"], ["short"], 1, 0, 1, EXTENSIONS, max_cycles=12, progress=False)
    plain = evaluate(["zero"], ["short"], 1, 0, 1, None, max_cycles=12, progress=False)
    row = rows[0]
    assert row["error"] == "" and "violations_slow_joints" in row
    seed = case_episode_seed(0, "short", 0)
    env = uvms_env.parallel_env("short", seed=seed, max_cycles=12, **EXTENSIONS)
    env.reset(seed=seed)
    total, info = 0.0, {}
    while env.agents:
        _, r, _, _, info = env.step({a: np.zeros(8) for a in env.agents})
        total += r[env.possible_agents[0]]
    metrics = episode_metrics(info[env.possible_agents[0]])
    assert row["violations_slow_joints"] == metrics["violations_slow_joints"]
    assert row["excess_slow_joints"] == pytest.approx(metrics["excess_slow_joints"])
    assert row["return"] == pytest.approx(total, abs=TOL)
    assert row["return"] != pytest.approx(plain[0]["return"], abs=1e-6)  # they took effect
