"""Extra pure delay in the loop, added to the actuators' history-buffer delay."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Effect, Param, finite, register, require_each


@register
@dataclass(eq=False)
class Delay(Effect):
    """Extra loop delay ``delay`` (s; scalar or (n,)), realized by MuJoCo's actuator delay buffers."""

    delay: Param = 0.0
    name = "delay"
    target = "model"

    def validate(self) -> None:
        finite(self.name, delay=self.delay)
        d = np.asarray(self.delay)
        require_each(d >= 0, self.name, self.delay, lambda v: f"delay must be >= 0 s, got {v}")
        require_each(d <= 1.0, self.name, self.delay, lambda v: f"delay {v} s is longer than the 1 s the buffers hold")
