"""Measurement rounded to multiples of ``step`` (pixelation of a camera)."""

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


@register
@dataclass(eq=False)
class Quantization(SignalEffect):
    """Round the measurement to multiples of ``step`` (output units, >= 0; scalar or (n,); 0: unchanged)."""

    step: Param = 0.01
    name = "quantization"
    session = SessionTerm(
        param="step", range=">0", identity=0.0, table=8, chain=9,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.02, 0.6, n) * sc["amp"],
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"step": rng.uniform(0.1, 0.3) * amp},
    )
    target = "measurement"

    def validate(self) -> None:
        finite(self.name, step=self.step)
        require_each(np.asarray(self.step) >= 0, self.name, self.step,
                     lambda v: f"step must be >= 0 (0: no quantization), got {v}")  # fmt: skip

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        step = np.broadcast_to(batched(self.step, n, self.name, "step"), (n,))
        self._on = step > 0
        self._all_on = bool(self._on.all())
        self._step = step if self._all_on else np.where(self._on, step, 1.0)

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        q = np.round(y / self._step) * self._step
        return q if self._all_on else np.where(self._on, q, y)
