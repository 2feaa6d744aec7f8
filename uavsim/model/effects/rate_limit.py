"""Actuator slew-rate limit: the command moves at most ``rate`` per second."""

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import (
    Param,
    SessionTerm,
    SignalEffect,
    batched,
    number,
    register,
    require_each,
)


def _phase(rate: float, freq_hz: float, h: float) -> float:
    """Phase lag, rad, of a relay cycle's fundamental through the limit: the +-``h`` square wave becomes a
    trapezoid whose ramps take ``2 h / rate`` and centre ``h / rate`` after each switch (a triangle, a
    quarter period, once the ramps fill the half period)."""
    return min(2 * math.pi * freq_hz * h / rate, math.pi / 2)


def _draw(rng, period, h, amp, noise_std, rate_hz):
    # a full 2*(2h) swing takes 5-15% of the period
    return {"rate": 4 * h / (rng.uniform(0.05, 0.15) * period)}


@register
@dataclass(eq=False)
class RateLimit(SignalEffect):
    """Slew at most ``rate`` command units per second (> 0; scalar or (n,); inf: no limit), at the control rate."""

    rate: Param = 1.0
    name = "rate_limit"
    session = SessionTerm(
        param="rate", range=">0", identity=math.inf, table=6, chain=4,
        grid=lambda sc, noise_std, rate_hz, n: 4 * sc["h_max"] / (np.geomspace(0.01, 0.4, n) * sc["period"]),
        draw=_draw,
        phase=_phase,
    )
    target = "command"

    def validate(self) -> None:
        number(self.name, rate=self.rate)
        require_each(np.asarray(self.rate) > 0, self.name, self.rate, lambda v: f"rate must be > 0 per s, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        rate = np.broadcast_to(batched(self.rate, n, self.name, "rate"), (n,))
        self._on = np.isfinite(rate)
        self._all_on = bool(self._on.all())
        self._step = rate / self.rate_hz
        self.prev = np.zeros(n)

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        self.prev = self.prev + np.clip(u - self.prev, -self._step, self._step)
        # prev + (u - prev) is not always u in floating point: unlimited episodes pass u itself
        return self.prev.copy() if self._all_on else np.where(self._on, self.prev, u)
