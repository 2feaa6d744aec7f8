"""Extra first-order lag on the actuator command.

MuJoCo's ``filterexact`` dynamics already carry the propulsion lag T_prop, and
an actuator has one dynamics stage, so the extra lag runs on the command at
the control rate. The command is piecewise constant between samples, so the
discretization ``x+ = a x + (1 - a) u``, ``a = exp(-Ts/T)`` is exact at the
samples; the lagged command is then held for one sample. ``T = 0`` means no
lag stage at all (the command passes unchanged, without the one-sample hold),
so that episodes of a batch without the effect can share it.
"""

import math
from dataclasses import dataclass

import numpy as np

from uavsim.model.effects.base import (
    Param,
    SessionTerm,
    SignalEffect,
    batched,
    finite,
    register,
    require_each,
)


@register
@dataclass(eq=False)
class Lag(SignalEffect):
    """First-order lag of time constant ``T`` (s, >= 0; scalar or (n,); 0: no lag) on the command."""

    T: Param = 0.05
    name = "lag"
    session = SessionTerm(
        param="T", range=">0", identity=0.0, table=2, chain=3,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.01 * sc["period"], 0.3 * sc["period"], n),
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"T": rng.uniform(0.04, 0.12) * period},
        phase=lambda T, freq_hz, h: math.atan(2 * math.pi * freq_hz * T),
    )
    target = "command"

    def validate(self) -> None:
        finite(self.name, T=self.T)
        require_each(np.asarray(self.T) >= 0, self.name, self.T, lambda v: f"T must be >= 0 s (0: no lag), got {v}")

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        T = np.broadcast_to(batched(self.T, n, self.name, "T"), (n,))
        self._on = T > 0
        self._all_on = bool(self._on.all())
        with np.errstate(divide="ignore"):
            self.a = np.where(self._on, np.exp(-1.0 / (rate_hz * np.where(self._on, T, 1.0))), 0.0)
        self.x = np.zeros(n)

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        out = self.x if self._all_on else np.where(self._on, self.x, u)
        self.x = self.a * self.x + (1.0 - self.a) * u
        return out
