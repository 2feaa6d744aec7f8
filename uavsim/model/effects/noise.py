"""Extra white Gaussian measurement noise (the session vocabulary's ``noise``)."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, SignalEffect, batched, finite, register, require_each


@register
@dataclass(eq=False)
class Noise(SignalEffect):
    """Add zero-mean Gaussian noise of standard deviation ``std`` (output units, >= 0; scalar or (n,))."""

    std: Param = 0.0
    name = "noise"
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, std=self.std)
        require_each(np.asarray(self.std) >= 0, self.name, self.std, lambda v: f"std must be >= 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._std = batched(self.std, n, self.name, "std")

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        return y + self._std * self.rng.standard_normal(y.shape)
