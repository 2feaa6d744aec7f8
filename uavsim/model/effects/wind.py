"""Wind: drag force from the air speed.

The body's translational damping (the lumped drag that sets T2) acts on the
velocity relative to the air. The joint damping already pulls with
``-c v``; wind adds ``c w(t)``, so the total is ``c (w - v)``. ``gust_std``
adds Dryden-like turbulence: white noise through a first-order filter of
time constant ``gust_T``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, batched, finite, register, require_each
from uavsim.model.effects.base_force import ForceEffect


@register
@dataclass(eq=False)
class Wind(ForceEffect):
    """Steady wind of ``speed`` m/s from ``direction_deg`` (0 = blowing towards +x), plus gusts.

    Every parameter is a scalar or an (n,) array (one value per episode).
    """

    speed: Param = 5.0
    direction_deg: Param = 0.0
    gust_std: Param = 0.0
    gust_T: Param = 1.0
    name = "wind"

    def validate(self) -> None:
        finite(self.name, speed=self.speed, direction_deg=self.direction_deg, gust_std=self.gust_std, gust_T=self.gust_T)
        require_each(np.asarray(self.speed) >= 0, self.name, self.speed, lambda v: f"speed must be >= 0 m/s, got {v}")
        require_each(np.asarray(self.gust_std) >= 0, self.name, self.gust_std, lambda v: "gust_std must be >= 0 m/s")
        require_each(np.asarray(self.gust_T) > 0, self.name, self.gust_T, lambda v: "gust_T must be > 0 s")

    def reset(self, n, rate_hz, rng, drag_Ns_per_m):
        super().reset(n, rate_hz, rng, drag_Ns_per_m)
        p = {k: np.broadcast_to(batched(v, self.n, self.name, k), (self.n,)) for k, v in self.params().items()}
        d = np.radians(p["direction_deg"])
        self._w = np.stack([p["speed"] * np.cos(d), p["speed"] * np.sin(d), np.zeros(self.n)], axis=1)
        self.gust = np.zeros((self.n, 2))
        self.a = np.exp(-1.0 / (rate_hz * p["gust_T"]))[:, None]
        self._gust_scale = (p["gust_std"] * np.sqrt(1 - self.a[:, 0] ** 2))[:, None]
        self._gusty = bool(np.any(p["gust_std"] > 0))

    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        w = self._w.copy()
        if self._gusty:
            self.gust = self.a * self.gust + self._gust_scale * self.rng.standard_normal(self.gust.shape)
            w[:, :2] += self.gust
        return self.drag * w
