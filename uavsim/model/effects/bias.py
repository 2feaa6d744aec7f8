"""Constant disturbance added at the actuator."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register


@register
@dataclass
class Bias(SignalEffect):
    """Add ``offset`` (command units) to the command."""

    offset: float = 0.0
    name = "bias"
    target = "command"

    def validate(self) -> None:
        finite(self.name, offset=self.offset)

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return u + self.offset
