"""Extra white Gaussian measurement noise (the session vocabulary's ``noise``)."""

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


def _grid(sc, noise_std, rate_hz, n):
    base = noise_std if noise_std > 0 else 0.01 * sc["amp"]
    return np.geomspace(0.3, 8.0, n) * base


@register
@dataclass(eq=False)
class Noise(SignalEffect):
    """Add zero-mean Gaussian noise of standard deviation ``std`` (output units, >= 0; scalar or (n,))."""

    std: Param = 0.0
    name = "noise"
    session = SessionTerm(
        param="std", range=">=0", identity=0.0, table=11, chain=8,
        grid=_grid,
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"std": rng.uniform(1.5, 4.0) * noise_std},
    )
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, std=self.std)
        require_each(np.asarray(self.std) >= 0, self.name, self.std, lambda v: f"std must be >= 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._std = batched(self.std, n, self.name, "std")

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        return y + self._std * self.rng.standard_normal(y.shape)

    def trace(self, m, T, rate_hz, rng):
        return np.broadcast_to(np.asarray(self.std, dtype=np.float64), (m,)) * rng.standard_normal((T, m))
