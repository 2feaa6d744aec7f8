"""Loop gain multiplied by a factor (thrust scaling of the loop's command)."""

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Effect, Param, finite, register, require_each


@register
@dataclass(eq=False)
class Gain(Effect):
    """Loop gain times ``factor`` (> 0; scalar or (n,))."""

    factor: Param = 1.0
    name = "gain"
    target = "model"

    def validate(self) -> None:
        finite(self.name, factor=self.factor)
        require_each(np.asarray(self.factor) > 0, self.name, self.factor, lambda v: f"factor must be > 0, got {v}")
