"""Actuator command clipped to [-limit, limit]."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class Saturation(SignalEffect):
    """Clip the command to ``[-limit, limit]`` (command units, > 0)."""

    limit: float = 1.0
    name = "saturation"
    target = "command"

    def validate(self) -> None:
        finite(self.name, limit=self.limit)
        require(self.limit > 0, self.name, f"limit must be > 0, got {self.limit}")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return np.clip(u, -self.limit, self.limit)
