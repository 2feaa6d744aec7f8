"""Small discrete filters the testbed's sensors and hidden effects are built from.

Written for the testbed on its own (the workflow's effects live in
``uavsim.model.effects`` and must not be what makes the "measured" data).

    lp = Biquad.butter_lowpass(cutoff_hz=80.0, rate_hz=1000.0, shape=(3,))
    y = lp(x)          # x, y: (3,)
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Biquad", "SecondOrderLag"]


class Biquad:
    """Direct-form-II-transposed second-order section, one per element of ``shape``."""

    def __init__(self, b: tuple[float, float, float], a: tuple[float, float, float], shape=()):
        self.b0, self.b1, self.b2 = (float(v) / a[0] for v in b)
        self.a1, self.a2 = float(a[1]) / a[0], float(a[2]) / a[0]
        self.z1 = np.zeros(shape)
        self.z2 = np.zeros(shape)

    @classmethod
    def butter_lowpass(cls, cutoff_hz: float, rate_hz: float, shape=()) -> Biquad:
        """2nd-order Butterworth low-pass by the bilinear transform with the cut-off prewarped."""
        fc = min(cutoff_hz, 0.45 * rate_hz)
        k = math.tan(math.pi * fc / rate_hz)
        q = 1.0 / math.sqrt(2.0)
        norm = 1.0 + k / q + k * k
        b = (k * k / norm, 2 * k * k / norm, k * k / norm)
        a = (1.0, 2.0 * (k * k - 1.0) / norm, (1.0 - k / q + k * k) / norm)
        return cls(b, a, shape)

    def prime(self, x) -> None:
        """Set the state to the steady state of a constant input ``x``."""
        x = np.asarray(x, dtype=np.float64)
        # y = x in steady state: z1 = y - b0 x, z2 = b2 x - a2 y
        self.z2 = (self.b2 - self.a2) * x + np.zeros_like(self.z2)
        self.z1 = x - self.b0 * x + np.zeros_like(self.z1)

    def __call__(self, x):
        y = self.b0 * x + self.z1
        self.z1 = self.b1 * x - self.a1 * y + self.z2
        self.z2 = self.b2 * x - self.a2 * y
        return y


class SecondOrderLag:
    """``x'' + 2 zeta w x' + w^2 x = w^2 u`` with ``u`` held over each step (exact discretization)."""

    def __init__(self, freq_hz: float, zeta: float, dt_s: float):
        w = 2.0 * math.pi * freq_hz
        A = np.array([[0.0, 1.0], [-w * w, -2.0 * zeta * w]])
        B = np.array([0.0, w * w])
        # exp([[A, B], [0, 0]] dt) gives the step's transition and input maps
        M = np.zeros((3, 3))
        M[:2, :2], M[:2, 2] = A * dt_s, B * dt_s
        E = _expm(M)
        self.Ad, self.Bd = E[:2, :2], E[:2, 2]
        self.x = np.zeros(2)

    def reset(self, u0: float) -> None:
        self.x = np.array([float(u0), 0.0])

    def __call__(self, u: float) -> float:
        self.x = self.Ad @ self.x + self.Bd * u
        return float(self.x[0])


def _expm(M: np.ndarray) -> np.ndarray:
    from scipy.linalg import expm

    return expm(M)
