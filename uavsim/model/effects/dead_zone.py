"""Actuator dead zone: ignores |u| < width and subtracts width beyond."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class DeadZone(SignalEffect):
    """Dead zone of half-width ``width`` (command units, >= 0)."""

    width: float = 0.0
    name = "dead_zone"
    target = "command"

    def validate(self) -> None:
        finite(self.name, width=self.width)
        require(self.width >= 0, self.name, f"width must be >= 0, got {self.width}")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return np.sign(u) * np.maximum(np.abs(u) - self.width, 0.0)
