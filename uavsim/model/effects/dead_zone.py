"""Actuator dead zone: ignores |u| < width and subtracts width beyond."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import (
    Param,
    SessionTerm,
    SignalEffect,
    batched,
    finite,
    register,
    require_each,
)


@register
@dataclass(eq=False)
class DeadZone(SignalEffect):
    """Dead zone of half-width ``width`` (command units, >= 0; scalar or (n,); 0 leaves u unchanged)."""

    width: Param = 0.0
    name = "dead_zone"
    session = SessionTerm(
        param="width", range=">=0", identity=0.0, table=5, chain=5,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.03, 0.8, n) * sc["h_min"],
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"width": rng.uniform(0.15, 0.45) * h},
    )
    target = "command"

    def validate(self) -> None:
        finite(self.name, width=self.width)
        require_each(np.asarray(self.width) >= 0, self.name, self.width, lambda v: f"width must be >= 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._width = batched(self.width, n, self.name, "width")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        # sign(u) |u| == u exactly, so width 0 is the identity
        return np.sign(u) * np.maximum(np.abs(u) - self._width, 0.0)
