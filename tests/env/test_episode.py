"""The episode driver (``uvms_env.episode``): every decision timed, the applied action the
one ``execute`` returns, the env's metrics with ``policy_time_ms_*`` added."""

from __future__ import annotations

import numpy as np
import pytest

import uvms_env
from uvms_env.episode import Step, play

STEPS = 4


class Constant:
    def __init__(self, spec, value: float = 0.0) -> None:
        self.value = value
        self.stats: dict = {}
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.full(8, self.value, np.float32)


def _env():
    return uvms_env.parallel_env("short", max_cycles=STEPS, internal_wrench_every=0)


def test_the_driver_times_each_decision_and_applies_what_execute_returns():
    seen: list[Step] = []

    def zero(index, policy, obs, action):
        assert action[0] == pytest.approx(0.3)  # the policy's own decision comes in
        return np.zeros_like(action)

    pushed = play(_env(), lambda spec: Constant(spec, 0.3), 3, execute=zero, on_step=seen.append)
    still = play(_env(), Constant, 3)
    n = len(pushed.policies)
    assert pushed.steps == len(seen) == STEPS and pushed.decision_ms.shape == (STEPS, n)
    assert [s.index for s in seen] == list(range(STEPS))
    assert all(not a.any() for s in seen for a in s.actions.values())
    assert all(p.resets == 1 for p in pushed.policies.values())
    timing = {k: pushed.metrics[f"policy_time_ms_{k}"] for k in ("median", "p95", "max")}
    assert 0.0 < timing["median"] <= timing["p95"] <= timing["max"]
    assert timing["max"] == pytest.approx(pushed.decision_ms.max())
    # the applied zeros, not the policy's push, reached the env
    assert pushed.metrics["control_effort"] == still.metrics["control_effort"]
    assert pushed.metrics["return"] == still.metrics["return"]
    assert pushed.end == "max_cycles" and pushed.metrics["episode_steps"] == STEPS
    unfiltered = play(_env(), lambda spec: Constant(spec, 0.3), 3)
    assert unfiltered.metrics["control_effort"] > still.metrics["control_effort"]


def test_a_policy_error_propagates():
    class Broken(Constant):
        def act(self, obs: np.ndarray) -> np.ndarray:
            raise RuntimeError("broken")

    with pytest.raises(RuntimeError, match="broken"):
        play(_env(), Broken, 0)
