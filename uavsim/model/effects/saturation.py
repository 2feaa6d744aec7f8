"""Actuator command clipped to [-limit, limit]."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, SignalEffect, batched, number, register, require_each


@register
@dataclass(eq=False)
class Saturation(SignalEffect):
    """Clip the command to ``[-limit, limit]`` (command units, > 0; scalar or (n,); inf: no limit)."""

    limit: Param = 1.0
    name = "saturation"
    target = "command"

    def validate(self) -> None:
        number(self.name, limit=self.limit)
        require_each(np.asarray(self.limit) > 0, self.name, self.limit, lambda v: f"limit must be > 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._limit = batched(self.limit, n, self.name, "limit")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return np.clip(u, -self._limit, self._limit)
