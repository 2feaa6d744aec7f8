"""Measurement sampled at a camera frame rate and held between frames."""

import math
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


def _phase(rate_hz: float, freq_hz: float, h: float) -> float:
    """Phase lag, rad, of a cycle at ``freq_hz`` through a hold of ``rate_hz`` frames: half a frame's delay on
    average (as against the unheld signal; a loop sampled at the control rate already holds half a control
    period of it, :func:`uavsim.gap.workflow.candidate_phase` takes that off)."""
    return math.pi * freq_hz / rate_hz


def _draw(rng, period, h, amp, noise_std, rate_hz):
    lo, hi = 15.0, min(0.5 * rate_hz, 1.0 / (0.03 * period))
    return {"rate_hz": float(math.exp(rng.uniform(math.log(lo), math.log(max(hi, lo * 1.01)))))}


@register
@dataclass(eq=False)
class SampleHold(SignalEffect):
    """Sample the measurement at ``rate_hz`` (> 0, <= the control rate; scalar or (n,)) and hold it.

    A new frame is taken at control sample ``k`` when ``floor(k * rate_hz /
    control_rate)`` advances, so a 60 Hz camera on a 200 Hz loop holds each
    frame for 3 or 4 samples, as a real frame clock beating against the loop.
    ``rate_hz`` equal to the control rate takes every sample (no effect).
    """

    rate_hz: Param = 60.0
    name = "sample_hold"
    session = SessionTerm(
        param="rate_hz", range=">0", identity=math.nan, table=9, chain=10,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(4.0, rate_hz / 1.5, n),
        draw=_draw,
        cap=lambda rate_hz: rate_hz,  # a frame rate above the control rate holds nothing
        identity_is_rate=True,
        phase=_phase,
    )
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, rate_hz=self.rate_hz)
        require_each(np.asarray(self.rate_hz) > 0, self.name, self.rate_hz, lambda v: f"rate_hz must be > 0, got {v}")

    def reset(self, n, rate_hz, rng):
        # not SignalEffect.reset: ``rate_hz`` is this effect's frame rate, not the control rate
        hold = batched(self.rate_hz, n, self.name, "rate_hz")
        require_each(np.asarray(hold) <= rate_hz * (1 + 1e-9), self.name, hold,
                     lambda v: f"rate_hz {v} exceeds the control rate {rate_hz} Hz")  # fmt: skip
        self.control_rate_hz = float(rate_hz)
        self._ratio = np.asarray(hold) / self.control_rate_hz
        self.n = int(n)
        self.rng = rng
        self.held = None

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        frame = np.floor(k * self._ratio + 1e-9)
        prev = np.floor((k - 1) * self._ratio + 1e-9)
        if self.held is None:
            self.held = np.array(y, dtype=np.float64, copy=True)
        elif self._ratio.ndim == 0:
            if frame != prev:
                self.held = np.array(y, dtype=np.float64, copy=True)
        else:
            self.held = np.where(frame != prev, y, self.held)
        return self.held.copy()
