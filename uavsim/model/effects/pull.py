"""Pull: an external force profile (a tether pulled, then released)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import finite, register, require
from uavsim.model.effects.base_force import ForceEffect

_AXES = {"x": 0, "y": 1, "z": 2}


@register
@dataclass
class Pull(ForceEffect):
    """Force ``force_N`` along ``axis`` from ``t_start`` until ``t_release`` (s), ramped over ``ramp_s``."""

    force_N: float = 10.0
    axis: str = "x"
    t_start: float = 2.0
    t_release: float = 6.0
    ramp_s: float = 0.5
    name = "pull"

    def validate(self) -> None:
        finite(self.name, force_N=self.force_N, t_start=self.t_start, t_release=self.t_release, ramp_s=self.ramp_s)
        require(self.axis in _AXES, self.name, f"axis must be x, y or z, got {self.axis!r}")
        require(self.t_release > self.t_start >= 0, self.name, "need 0 <= t_start < t_release")
        require(self.ramp_s >= 0, self.name, "ramp_s must be >= 0 s")

    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        f = np.zeros((self.n, 3))
        if self.t_start <= t < self.t_release:
            ramp = 1.0 if self.ramp_s == 0 else min(1.0, (t - self.t_start) / self.ramp_s)
            f[:, _AXES[self.axis]] = self.force_N * ramp
        return f
