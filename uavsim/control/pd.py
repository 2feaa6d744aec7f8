"""The step-test PD controller with a filtered derivative, vectorized.

Normative sampled semantics of ``docs/formats/session.md`` ("step"):
``raw_k = (e_k - e_{k-1}) / Ts`` (0 on the first sample),
``d_k = d_{k-1} + a (raw_k - d_{k-1})`` with ``a = Ts N / (1 + Ts N)`` and
``N = 2 pi derivative_filter_hz``, ``u_k = kp e_k + kd d_k``.

    pd = PD(kp=2.3, kd=0.85, derivative_filter_hz=7.96, rate_hz=200.0, n=16)
    u = pd(e)       # e, u: (16,)
"""

from __future__ import annotations

import numpy as np

from uavsim.errors import UserError


class PD:
    """``n`` PD controllers with first-order filtered derivative, one call per sample.

    Parameters
    ----------
    kp : float or array (n,)
        Proportional gain, command units per output unit.
    kd : float or array (n,)
        Derivative gain, command units per (output unit / s).
    derivative_filter_hz : float or array (n,)
        Cut-off of the first-order derivative filter, Hz (> 0).
    rate_hz : float
        Controller rate, Hz.
    n : int
        Batch size.
    """

    kind = "step"

    def __init__(self, kp, kd, derivative_filter_hz, rate_hz: float, n: int):
        shape = (int(n),)
        self.kp = np.broadcast_to(np.asarray(kp, dtype=np.float64), shape).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=np.float64), shape).copy()
        fhz = np.broadcast_to(np.asarray(derivative_filter_hz, dtype=np.float64), shape)
        if not (np.all(np.isfinite(self.kp)) and np.all(np.isfinite(self.kd))):
            raise UserError("PD gains must be finite")
        if not np.all(np.isfinite(fhz)) or np.any(fhz <= 0):
            raise UserError("PD derivative_filter_hz must be > 0")
        if rate_hz <= 0:
            raise UserError(f"controller rate must be > 0 Hz, got {rate_hz}")
        self.Ts = 1.0 / float(rate_hz)
        wn = 2.0 * np.pi * fhz
        self.a = self.Ts * wn / (1.0 + self.Ts * wn)
        self.n = int(n)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self.e_prev = np.zeros(self.n)
        self.d = np.zeros(self.n)

    def __call__(self, e: np.ndarray) -> np.ndarray:
        e = np.asarray(e, dtype=np.float64)
        raw = (e - self.e_prev) / self.Ts if self.k > 0 else np.zeros(self.n)
        self.d = self.d + self.a * (raw - self.d)
        self.e_prev = e.copy()
        self.k += 1
        return self.kp * e + self.kd * self.d
