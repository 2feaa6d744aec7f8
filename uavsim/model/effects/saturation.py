"""Actuator command clipped to [-limit, limit]."""

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import (
    Param,
    SessionTerm,
    SignalEffect,
    batched,
    number,
    register,
    require_each,
)


@register
@dataclass(eq=False)
class Saturation(SignalEffect):
    """Clip the command to ``[-limit, limit]`` (command units, > 0; scalar or (n,); inf: no limit)."""

    limit: Param = 1.0
    name = "saturation"
    session = SessionTerm(
        param="limit", range=">0", identity=math.inf, table=4, chain=6,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.15, 1.0, n) * sc["umax"],
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"limit": rng.uniform(0.5, 0.85) * 2 * h},
    )
    target = "command"

    def validate(self) -> None:
        number(self.name, limit=self.limit)
        require_each(np.asarray(self.limit) > 0, self.name, self.limit, lambda v: f"limit must be > 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._limit = batched(self.limit, n, self.name, "limit")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return np.clip(u, -self._limit, self._limit)
