"""Measurement sampled at a camera frame rate and held between frames."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class SampleHold(SignalEffect):
    """Sample the measurement at ``rate_hz`` (<= the control rate) and hold it.

    A new frame is taken at control sample ``k`` when ``floor(k * rate_hz /
    control_rate)`` advances, so a 60 Hz camera on a 200 Hz loop holds each
    frame for 3 or 4 samples, as a real frame clock beating against the loop.
    """

    rate_hz: float = 60.0
    name = "sample_hold"
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, rate_hz=self.rate_hz)
        require(self.rate_hz > 0, self.name, f"rate_hz must be > 0, got {self.rate_hz}")

    def reset(self, n, rate_hz, rng):
        if self.rate_hz > rate_hz * (1 + 1e-9):
            require(False, self.name, f"rate_hz {self.rate_hz} exceeds the control rate {rate_hz} Hz")
        self.control_rate_hz = float(rate_hz)
        self.n = int(n)
        self.rng = rng
        self.held = None

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        frame = np.floor(k * self.rate_hz / self.control_rate_hz + 1e-9)
        prev = np.floor((k - 1) * self.rate_hz / self.control_rate_hz + 1e-9)
        if self.held is None or frame != prev:
            self.held = np.array(y, dtype=np.float64, copy=True)
        return self.held.copy()
