"""Extra pure delay in the loop, added to the actuators' history-buffer delay."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Effect, Param, SessionTerm, finite, register, require_each


@register
@dataclass(eq=False)
class Delay(Effect):
    """Extra loop delay ``delay`` (s; scalar or (n,)), realized by MuJoCo's actuator delay buffers."""

    delay: Param = 0.0
    name = "delay"
    session = SessionTerm(
        param="delay", range=">=0", identity=0.0, table=1, chain=1,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.01 * sc["period"], 0.3 * sc["period"], n),
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"delay": rng.uniform(0.04, 0.12) * period},
    )
    target = "model"

    def validate(self) -> None:
        finite(self.name, delay=self.delay)
        d = np.asarray(self.delay)
        require_each(d >= 0, self.name, self.delay, lambda v: f"delay must be >= 0 s, got {v}")
        require_each(d <= 1.0, self.name, self.delay, lambda v: f"delay {v} s is longer than the 1 s the buffers hold")
