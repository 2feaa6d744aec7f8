"""Constant disturbance added at the actuator."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, SessionTerm, SignalEffect, batched, finite, register


def _grid(sc, noise_std, rate_hz, n):
    half = np.geomspace(0.03, 0.8, n // 2 + 1) * sc["h_min"]
    return np.concatenate([-half[::-1], half])


def _draw(rng, period, h, amp, noise_std, rate_hz):
    return {"offset": float(rng.choice([-1, 1]) * rng.uniform(0.15, 0.4) * h)}


@register
@dataclass(eq=False)
class Bias(SignalEffect):
    """Add ``offset`` (command units; scalar or (n,)) to the command."""

    offset: Param = 0.0
    name = "bias"
    session = SessionTerm(
        param="offset", range="any", identity=0.0, table=7, chain=7,
        grid=_grid,
        draw=_draw,
    )
    target = "command"

    def validate(self) -> None:
        finite(self.name, offset=self.offset)

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._offset = batched(self.offset, n, self.name, "offset")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return u + self._offset
