"""The step-test PD controller with a filtered derivative, vectorized.

Normative sampled semantics of ``docs/formats/session.md`` ("step"):
``raw_k = (x_k - x_{k-1}) / Ts`` (0 on the first sample), where ``x = e``
(``derivative = "error"``, the default) or ``x = -y = e - r``
(``derivative = "measurement"``: a reference step sends no derivative kick),
``d_k = d_{k-1} + a (raw_k - d_{k-1})`` with ``a = Ts N / (1 + Ts N)`` and
``N = 2 pi derivative_filter_hz``, ``u_k = kp e_k + kd d_k``.

    pd = PD(kp=2.3, kd=0.85, derivative_filter_hz=7.96, rate_hz=200.0, n=16)
    u = pd(e)       # e, u: (16,)
    pdm = PD(2.3, 0.85, 7.96, 200.0, 16, derivative="measurement")
    u = pdm(e, r)   # the reference too (pdm.reads_reference): the derivative is of -y = e - r
"""

from __future__ import annotations

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import STEP_DERIVATIVES


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
    derivative : str or sequence of str (n,)
        What the derivative differentiates: ``"error"`` (``e``) or ``"measurement"``
        (``-y``, so that a reference step does not kick the command); per controller.

    Attributes
    ----------
    reads_reference : bool
        True when some controller differentiates the measurement: then every call
        must pass the reference ``r`` with the error (the loops test this attribute).
    """

    kind = "step"

    def __init__(self, kp, kd, derivative_filter_hz, rate_hz: float, n: int, *, derivative="error"):
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
        on = np.broadcast_to(np.asarray(derivative, dtype=object), shape)
        bad = sorted({str(v) for v in on if v not in STEP_DERIVATIVES})
        if bad:
            raise UserError(f"PD derivative must be one of {', '.join(STEP_DERIVATIVES)}, got {', '.join(bad)}")
        self.on_measurement = np.array([v == "measurement" for v in on], dtype=bool)
        self.reads_reference = bool(self.on_measurement.any())
        self.Ts = 1.0 / float(rate_hz)
        wn = 2.0 * np.pi * fhz
        self.a = self.Ts * wn / (1.0 + self.Ts * wn)
        self.n = int(n)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self.x_prev = np.zeros(self.n)
        self.d = np.zeros(self.n)

    def __call__(self, e: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
        e = np.asarray(e, dtype=np.float64)
        x = e
        if self.reads_reference:
            if r is None:
                raise UserError("a PD with the derivative on the measurement needs the reference r with the error")
            x = np.where(self.on_measurement, e - np.asarray(r, dtype=np.float64), e)
        raw = (x - self.x_prev) / self.Ts if self.k > 0 else np.zeros(self.n)
        self.d = self.d + self.a * (raw - self.d)
        self.x_prev = np.array(x, dtype=np.float64)
        self.k += 1
        return self.kp * e + self.kd * self.d
