"""Constant disturbance added at the actuator."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, SignalEffect, batched, finite, register


@register
@dataclass(eq=False)
class Bias(SignalEffect):
    """Add ``offset`` (command units; scalar or (n,)) to the command."""

    offset: Param = 0.0
    name = "bias"
    target = "command"

    def validate(self) -> None:
        finite(self.name, offset=self.offset)

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._offset = batched(self.offset, n, self.name, "offset")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return u + self._offset
