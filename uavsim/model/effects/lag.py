"""Extra first-order lag on the actuator command.

MuJoCo's ``filterexact`` dynamics already carry the propulsion lag T_prop, and
an actuator has one dynamics stage, so the extra lag runs on the command at
the control rate. The command is piecewise constant between samples, so the
discretization ``x+ = a x + (1 - a) u``, ``a = exp(-Ts/T)`` is exact at the
samples; the lagged command is then held for one sample.
"""

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import SignalEffect, finite, register, require


@register
@dataclass
class Lag(SignalEffect):
    """First-order lag of time constant ``T`` (s) on the command."""

    T: float = 0.05
    name = "lag"
    target = "command"

    def validate(self) -> None:
        finite(self.name, T=self.T)
        require(self.T > 0, self.name, f"T must be > 0 s, got {self.T}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self.a = math.exp(-1.0 / (rate_hz * self.T))
        self.x = None

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        if self.x is None:
            self.x = np.zeros_like(u)
        out = self.x.copy()
        self.x = self.a * self.x + (1.0 - self.a) * u
        return out
