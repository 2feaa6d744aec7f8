"""Extra pure delay in the loop, added to the actuators' history-buffer delay."""

from dataclasses import dataclass

from uavsim.model.effects.base import Effect, finite, register, require


@register
@dataclass
class Delay(Effect):
    """Extra loop delay ``delay`` (s), realized by MuJoCo's actuator delay buffers."""

    delay: float = 0.0
    name = "delay"
    target = "model"

    def validate(self) -> None:
        finite(self.name, delay=self.delay)
        require(self.delay >= 0, self.name, f"delay must be >= 0 s, got {self.delay}")
        require(self.delay <= 1.0, self.name, f"delay {self.delay} s is longer than the 1 s the buffers hold")
