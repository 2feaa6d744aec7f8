"""Extra white Gaussian measurement noise (the session vocabulary's ``noise``)."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, register, require


@register
@dataclass
class Noise(SignalEffect):
    """Add zero-mean Gaussian noise of standard deviation ``std`` (output units).

    ``std`` may be an array (n,) to give each episode its own level.
    """

    std: float = 0.0
    name = "noise"
    target = "measurement"

    def validate(self) -> None:
        s = np.asarray(self.std, dtype=np.float64)
        require(bool(np.all(np.isfinite(s))), self.name, "std must be finite")
        require(bool(np.all(s >= 0)), self.name, f"std must be >= 0, got {self.std}")

    def params(self):
        s = np.asarray(self.std)
        return {"std": float(s) if s.ndim == 0 else s}

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        return y + self.std * self.rng.standard_normal(y.shape)
