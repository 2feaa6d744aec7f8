"""Measurement rounded to multiples of ``step`` (pixelation of a camera)."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class Quantization(SignalEffect):
    """Round the measurement to multiples of ``step`` (output units, > 0)."""

    step: float = 0.01
    name = "quantization"
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, step=self.step)
        require(self.step > 0, self.name, f"step must be > 0, got {self.step}")

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        return np.round(y / self.step) * self.step
