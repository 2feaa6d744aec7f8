"""Loop gain multiplied by a factor (thrust scaling of the loop's command)."""

from dataclasses import dataclass

from uavsim.model.effects.base import Effect, finite, register, require


@register
@dataclass
class Gain(Effect):
    """Loop gain times ``factor`` (> 0)."""

    factor: float = 1.0
    name = "gain"
    target = "model"

    def validate(self) -> None:
        finite(self.name, factor=self.factor)
        require(self.factor > 0, self.name, f"factor must be > 0, got {self.factor}")
