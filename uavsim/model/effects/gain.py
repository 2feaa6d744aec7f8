"""Loop gain multiplied by a factor (thrust scaling of the loop's command)."""

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Effect, Param, SessionTerm, finite, register, require_each


def _draw(rng, period, h, amp, noise_std, rate_hz):
    u = rng.uniform
    return {"factor": float(math.exp(rng.choice([-1, 1]) * u(math.log(1.3), math.log(2.2))))}


@register
@dataclass(eq=False)
class Gain(Effect):
    """Loop gain times ``factor`` (> 0; scalar or (n,))."""

    factor: Param = 1.0
    name = "gain"
    session = SessionTerm(
        param="factor", range=">0", identity=1.0, table=3, chain=2,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(1 / 3, 3.0, n + 1),
        draw=_draw,
    )
    target = "model"

    def validate(self) -> None:
        finite(self.name, factor=self.factor)
        require_each(np.asarray(self.factor) > 0, self.name, self.factor, lambda v: f"factor must be > 0, got {v}")
