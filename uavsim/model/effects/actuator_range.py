"""The actuators' range: the command clipped to ``[low, high]`` around the hover trim.

Not a vocabulary effect (nothing the gap workflow searches for): it is what a
user knows of the vehicle, the command at which the mixer drives a motor to
its ESC's lowest or highest output (``[actuator]`` of a session,
``docs/formats/session.md``). A multirotor's range is asymmetric on the
collective thrust (more room down than up, or the reverse) and about
symmetric on the moments.

    eff = make_effect("actuator_range", low=-30.0, high=45.0)
"""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, SignalEffect, batched, finite, register, require_each


@register
@dataclass(eq=False)
class ActuatorRange(SignalEffect):
    """Clip the command to ``[low, high]`` (command units, ``low < 0 < high``; scalars or (n,))."""

    low: Param = -1.0
    high: Param = 1.0
    name = "actuator_range"
    target = "command"

    def validate(self) -> None:
        finite(self.name, low=self.low, high=self.high)
        require_each(np.asarray(self.low) < 0, self.name, self.low, lambda v: f"low must be < 0, got {v}")
        require_each(np.asarray(self.high) > 0, self.name, self.high, lambda v: f"high must be > 0, got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._low = batched(self.low, n, self.name, "low")
        self._high = batched(self.high, n, self.name, "high")

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        return np.clip(u, self._low, self._high)
