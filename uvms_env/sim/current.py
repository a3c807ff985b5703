"""Ocean current: first-order Gauss-Markov speed with a slowly wandering horizontal heading
(Fossen 2011, ch. 8): V_dot = -mu (V - V_mean) + w, w ~ N(0, sigma^2), clamped.

``OceanCurrent`` is one environment's walk; ``Currents`` is the one owner of the currents of
a batch of K environments (K = 1: the single ``Simulator``; K: the ``BatchedSimulator``):
each environment's preset, its draws at a reset and its walk every period.

May import: numpy and ``uvms_env.models``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from uvms_env.models import CurrentPreset


class OceanCurrent:
    def __init__(self, preset: CurrentPreset) -> None:
        self.preset = preset
        self.speed = 0.0
        self.heading = 0.0
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> None:
        """New episode: heading uniform, speed at the preset's mean (own stream from rng)."""
        self._rng = np.random.default_rng(rng.integers(2**63))
        self.heading = float(self._rng.uniform(-np.pi, np.pi))
        self.speed = self.preset.mean

    def step(self, dt: float) -> np.ndarray:
        """Advance by dt (Euler-Maruyama) and return the inertial current velocity (3,)."""
        p = self.preset
        if p.max == 0.0:
            return np.zeros(3)
        self.speed += (
            -p.mu * (self.speed - p.mean) * dt + p.sigma * np.sqrt(dt) * self._rng.normal()
        )
        self.speed = float(np.clip(self.speed, p.min, p.max))
        self.heading += p.heading_sigma * np.sqrt(dt) * self._rng.normal()
        return self.speed * np.array([np.cos(self.heading), np.sin(self.heading), 0.0])


class Currents:
    """The ocean currents of K environments, each its own walk (``OceanCurrent``) under its
    own preset, drawn from its own generator: Python per environment, since each one's
    draws come from its own stream (only while some current is on)."""

    def __init__(self, preset: CurrentPreset, k: int) -> None:
        self.models = [OceanCurrent(preset) for _ in range(k)]
        self.velocity = np.zeros((k, 3))  # the last period's, (K, 3) inertial m/s
        self.on = preset.max > 0.0

    def reset(
        self,
        rows: Sequence[int],
        generators: Sequence[np.random.Generator],
        presets: Sequence[CurrentPreset] | None = None,
    ) -> None:
        """New episodes in ``rows``: each draws its current from its generator (after the
        truth model's draws), under its ``presets`` entry (None: the one it has)."""
        changed = False
        for j, (i, rng) in enumerate(zip(rows, generators, strict=True)):
            if presets is not None and presets[j] is not self.models[i].preset:
                self.models[i] = OceanCurrent(presets[j])
                changed = True
            self.models[i].reset(rng)
        if changed:
            self.on = any(m.preset.max > 0.0 for m in self.models)

    def step(self, dt: float) -> np.ndarray | None:
        """Every environment's current over the next ``dt``: (K, 3), or None in still
        water everywhere (no draws)."""
        if not self.on:
            return None
        for i, model in enumerate(self.models):
            self.velocity[i] = model.step(dt)
        return self.velocity
