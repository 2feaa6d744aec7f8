"""Pull: an external force profile (a tether pulled, then released)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import Param, batched, finite, register, require, require_each
from uavsim.model.effects.base_force import ForceEffect

_AXES = {"x": 0, "y": 1, "z": 2}


@register
@dataclass(eq=False)
class Pull(ForceEffect):
    """Force ``force_N`` along ``axis`` from ``t_start`` until ``t_release`` (s), ramped over ``ramp_s``.

    The numeric parameters are scalars or (n,) arrays (one value per episode); ``axis`` is one of x, y, z.
    """

    force_N: Param = 10.0
    axis: str = "x"
    t_start: Param = 2.0
    t_release: Param = 6.0
    ramp_s: Param = 0.5
    name = "pull"

    def validate(self) -> None:
        finite(self.name, force_N=self.force_N, t_start=self.t_start, t_release=self.t_release, ramp_s=self.ramp_s)
        require(self.axis in _AXES, self.name, f"axis must be x, y or z, got {self.axis!r}")
        t0, t1 = np.asarray(self.t_start), np.asarray(self.t_release)
        require_each((t1 > t0) & (t0 >= 0), self.name, self.t_start, lambda v: "need 0 <= t_start < t_release")
        require_each(np.asarray(self.ramp_s) >= 0, self.name, self.ramp_s, lambda v: "ramp_s must be >= 0 s")

    def reset(self, n, rate_hz, rng, drag_Ns_per_m):
        super().reset(n, rate_hz, rng, drag_Ns_per_m)
        for k in ("force_N", "t_start", "t_release", "ramp_s"):
            batched(getattr(self, k), self.n, self.name, k)

    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        f = np.zeros((self.n, 3))
        on = (self.t_start <= t) & (t < self.t_release)
        ramp_s = np.asarray(self.ramp_s, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            ramp = np.where(ramp_s == 0, 1.0, np.minimum(1.0, (t - self.t_start) / np.where(ramp_s == 0, 1.0, ramp_s)))
        f[:, _AXES[self.axis]] = np.where(on, self.force_N * ramp, 0.0)
        return f
