"""Ocean current: first-order Gauss-Markov speed with a slowly wandering horizontal heading
(Fossen 2011, ch. 8): V_dot = -mu (V - V_mean) + w, w ~ N(0, sigma^2), clamped."""

from __future__ import annotations

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
