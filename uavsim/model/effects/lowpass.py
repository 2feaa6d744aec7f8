"""2nd-order Butterworth low-pass on the measurement, at the control rate."""

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from uavsim.model.effects.base import (
    Param,
    SessionTerm,
    SignalEffect,
    batched,
    number,
    register,
    require_each,
)


def _phase(cutoff_hz: float, freq_hz: float, h: float) -> float:
    """Phase lag, rad, of the (continuous) 2nd-order Butterworth at ``freq_hz`` (any relay amplitude ``h``)."""
    x = freq_hz / cutoff_hz
    return math.atan2(math.sqrt(2.0) * x, 1.0 - x * x)


def _draw(rng, period, h, amp, noise_std, rate_hz):
    f0 = 1.0 / period
    return {"cutoff_hz": float(min(f0 / rng.uniform(0.12, 0.35), 0.4 * rate_hz))}


@register
@dataclass(eq=False)
class Lowpass(SignalEffect):
    """Butterworth low-pass (order 2) with cut-off ``cutoff_hz`` (below Nyquist; scalar or (n,); inf: no filter).

    Each episode runs its own biquad in transposed direct form II (as
    ``scipy.signal.sosfilt``), started settled at its first sample, as a
    filter running since power-up.
    """

    cutoff_hz: Param = 20.0
    name = "lowpass"
    session = SessionTerm(
        param="cutoff_hz", range=">0", identity=math.inf, table=10, chain=11,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(min(0.3 / sc["period"], 0.4 * rate_hz), 0.45 * rate_hz, n),
        draw=_draw,
        cap=lambda rate_hz: 0.45 * rate_hz,
        phase=_phase,
    )
    target = "measurement"

    def validate(self) -> None:
        number(self.name, cutoff_hz=self.cutoff_hz)
        require_each(np.asarray(self.cutoff_hz) > 0, self.name, self.cutoff_hz,
                     lambda v: f"cutoff_hz must be > 0, got {v}")  # fmt: skip

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        nyq = rate_hz / 2
        cut = batched(self.cutoff_hz, n, self.name, "cutoff_hz")
        require_each((np.asarray(cut) < nyq) | np.isinf(cut), self.name, cut,
                     lambda v: f"cutoff {v} Hz is not below Nyquist ({nyq} Hz at {rate_hz} Hz)")  # fmt: skip
        cut = np.broadcast_to(cut, (n,))
        # per episode: numerator b (n, 3), denominator a (n, 3), settled state per unit input (n, 2);
        # an infinite cut-off is the identity biquad (b = a = [1, 0, 0], zero state)
        b, a, zi = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 2))
        b[:, 0] = a[:, 0] = 1.0
        for c in np.unique(cut[np.isfinite(cut)]):  # few distinct values even in a fitting batch
            sos = signal.butter(2, c, fs=rate_hz, output="sos")
            i = cut == c
            b[i], a[i], zi[i] = sos[0, :3], sos[0, 3:], signal.sosfilt_zi(sos)[0]
        self._b, self._a, self._zi0 = b.T.copy(), a.T.copy(), zi.T.copy()
        self._z = None

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        b, a = self._b, self._a
        if self._z is None:
            self._z = self._zi0 * y[None, :]
        z = self._z
        out = b[0] * y + z[0]
        self._z = np.stack([b[1] * y - a[1] * out + z[1], b[2] * y - a[2] * out])
        return out
