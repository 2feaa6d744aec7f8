"""2nd-order Butterworth low-pass on the measurement, at the control rate."""

from dataclasses import dataclass

import numpy as np
from scipy import signal

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class Lowpass(SignalEffect):
    """Butterworth low-pass (order 2) with cut-off ``cutoff_hz`` (below Nyquist)."""

    cutoff_hz: float = 20.0
    name = "lowpass"
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, cutoff_hz=self.cutoff_hz)
        require(self.cutoff_hz > 0, self.name, f"cutoff_hz must be > 0, got {self.cutoff_hz}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        nyq = rate_hz / 2
        require(self.cutoff_hz < nyq, self.name, f"cutoff {self.cutoff_hz} Hz is not below Nyquist ({nyq} Hz at {rate_hz} Hz)")
        self.sos = signal.butter(2, self.cutoff_hz, fs=rate_hz, output="sos")
        self.zi = None

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        if self.zi is None:
            # start settled at the first sample, as a filter running since power-up
            self.zi = signal.sosfilt_zi(self.sos)[:, :, None] * y[None, None, :]
        out, self.zi = signal.sosfilt(self.sos, y[None, :], axis=0, zi=self.zi)
        return out[0]
