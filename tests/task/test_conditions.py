"""Per-episode draws of the conditions (``randomize``, ``uvms_env.task.conditions``): what is
drawn, that an episode plays exactly the physics of an environment fixed at its draw, the
same in ``parallel_env`` and ``VectorEnv``, and clear errors for malformed draws."""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from uvms_env.task.conditions import ConditionDraws, Conditions, condition_draws
from uvms_env.vector import VectorEnv

DRAWS = {"current": ["none", "mild", "strong"], "mismatch": [0.02, 0.2]}
STEPS = 15


def _actions(n: int, steps: int = STEPS) -> np.ndarray:
    return np.random.default_rng(4).uniform(-0.4, 0.4, (steps, n, 8))


def _play(env, seed: int, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    obs, _ = env.reset(seed=seed)
    agents = env.possible_agents
    seen, rewards = [np.stack([obs[a] for a in agents])], []
    for act in actions:
        obs, rew, *_ = env.step({a: act[i] for i, a in enumerate(agents)})
        seen.append(np.stack([obs[a] for a in agents]))
        rewards.append(rew[agents[0]])
    return np.stack(seen), np.array(rewards)


def test_draws_cover_the_sets_and_ranges_and_repeat_per_seed():
    draws = condition_draws(DRAWS)
    base = Conditions("none", 0.0)
    drawn = [draws.draw(seed, base) for seed in range(300)]
    assert {c.current for c in drawn} == set(DRAWS["current"])
    m = np.array([c.mismatch for c in drawn])
    assert m.min() >= 0.02 and m.max() <= 0.2 and m.max() - m.min() > 0.15
    assert drawn == [draws.draw(seed, base) for seed in range(300)]  # keyed by the seed
    # a key left out keeps the scenario's value
    only = condition_draws({"mismatch": 0.05})
    assert only.draw(7, Conditions("mild", 0.3)) == Conditions("mild", 0.05)


def test_an_episode_plays_the_physics_of_its_drawn_conditions():
    """The randomized environment, reset with a seed, is bit for bit the environment
    fixed at the conditions it drew (same truth-model and current draws): the draws add
    nothing but the choice of preset and mismatch. Two seeds that drew different currents
    show that the draw matters."""
    actions = _actions(3)
    played = {}
    for seed in (5, 6, 7, 8):
        env = uvms_env.parallel_env("random", n_agents=3, randomize=DRAWS, max_cycles=STEPS)
        obs, rew = _play(env, seed, actions)
        c = env._core.conditions[0]
        fixed = uvms_env.parallel_env(
            "random", n_agents=3, current=c.current, mismatch=c.mismatch, max_cycles=STEPS
        )
        obs_fixed, rew_fixed = _play(fixed, seed, actions)
        np.testing.assert_array_equal(obs, obs_fixed)
        np.testing.assert_array_equal(rew, rew_fixed)
        played[seed] = c
    assert len({c.current for c in played.values()}) > 1


def test_vector_env_draws_as_the_single_env():
    k, seed = 3, 11
    actions = _actions(2)
    venv = VectorEnv("random", num_envs=k, n_agents=2, randomize=DRAWS, max_cycles=STEPS)
    obs, _ = venv.reset(seed=seed)
    drawn = list(venv._core.conditions)  # the last step's automatic resets draw anew
    vobs = [obs]
    for act in actions:
        obs, *_ = venv.step(np.broadcast_to(act, (k, 2, 8)))
        vobs.append(obs)
    vobs = np.stack(vobs)
    for i in range(k):
        env = uvms_env.parallel_env("random", n_agents=2, randomize=DRAWS, max_cycles=STEPS)
        single, _ = _play(env, seed + i, actions)
        assert env._core.conditions[0] == drawn[i]
        # the last row is the automatic reset's first observation in the vector env
        np.testing.assert_allclose(single[:-1], vobs[:-1, i], rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [
        ({"current": "gale"}, ValueError, "current"),
        ({"current": []}, TypeError, "non-empty"),
        ({"mismatch": [0.2, 0.1]}, ValueError, "low <= high"),
        ({"mismatch": [0.1, 0.7]}, ValueError, "mismatch"),
        ({"mismatch": "0.1"}, TypeError, "number or \\[low, high\\]"),
        ({"wind": 1}, ValueError, "unknown key"),
        (["mild"], TypeError, "dict"),
    ],
)
def test_malformed_draws_are_named(value, error, match):
    with pytest.raises(error, match=match):
        uvms_env.parallel_env("random", randomize=value)


def test_no_draw_is_no_randomize():
    assert condition_draws(None) is None and condition_draws({}) is None
    draws = ConditionDraws(("mild",), None)
    assert condition_draws(draws) is draws
    assert draws.describe() == {"current": ["mild"]}
