"""Wind: drag force from the air speed.

The body's translational damping (the lumped drag that sets T2) acts on the
velocity relative to the air. The joint damping already pulls with
``-c v``; wind adds ``c w(t)``, so the total is ``c (w - v)``. ``gust_std``
adds Dryden-like turbulence: white noise through a first-order filter of
time constant ``gust_T``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import finite, register, require
from uavsim.model.effects.base_force import ForceEffect


@register
@dataclass
class Wind(ForceEffect):
    """Steady wind of ``speed`` m/s from ``direction_deg`` (0 = blowing towards +x), plus gusts."""

    speed: float = 5.0
    direction_deg: float = 0.0
    gust_std: float = 0.0
    gust_T: float = 1.0
    name = "wind"

    def validate(self) -> None:
        finite(self.name, speed=self.speed, direction_deg=self.direction_deg, gust_std=self.gust_std, gust_T=self.gust_T)
        require(self.speed >= 0, self.name, f"speed must be >= 0 m/s, got {self.speed}")
        require(self.gust_std >= 0, self.name, "gust_std must be >= 0 m/s")
        require(self.gust_T > 0, self.name, "gust_T must be > 0 s")

    def reset(self, n, rate_hz, rng, drag_Ns_per_m):
        super().reset(n, rate_hz, rng, drag_Ns_per_m)
        self.gust = np.zeros((self.n, 2))
        self.a = math.exp(-1.0 / (rate_hz * self.gust_T))

    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        d = math.radians(self.direction_deg)
        w = np.zeros((self.n, 3))
        w[:, 0] = self.speed * math.cos(d)
        w[:, 1] = self.speed * math.sin(d)
        if self.gust_std > 0:
            scale = self.gust_std * math.sqrt(1 - self.a**2)
            self.gust = self.a * self.gust + scale * self.rng.standard_normal(self.gust.shape)
            w[:, :2] += self.gust
        return self.drag * w
