"""Actuator slew-rate limit: the command moves at most ``rate`` per second."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class RateLimit(SignalEffect):
    """Slew at most ``rate`` command units per second (sampled at the control rate)."""

    rate: float = 1.0
    name = "rate_limit"
    target = "command"

    def validate(self) -> None:
        finite(self.name, rate=self.rate)
        require(self.rate > 0, self.name, f"rate must be > 0 per s, got {self.rate}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self.prev = None

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        if self.prev is None:
            self.prev = np.zeros_like(u)
        step = self.rate / self.rate_hz
        self.prev = self.prev + np.clip(u - self.prev, -step, step)
        return self.prev.copy()
