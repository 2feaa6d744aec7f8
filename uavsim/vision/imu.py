"""Accelerometer of the IMU along one inertial axis (Xsens MTi-670 class, 200 Hz).

The Kalman filter (``uavsim.vision.kalman``) integrates the accelerometer,
rotated into the inertial frame, between camera frames. What it gets is the
true specific acceleration sampled at ``rate_hz``, plus white noise of
``noise_std_mps2`` and a bias: a constant ``bias_mps2`` (the part that the
hover calibration leaves; the filter's ``a_b`` state absorbs it) plus a slow
random walk of ``bias_walk_mps2_per_sqrt_s``. The true acceleration is the
mean over the last control period (velocity difference over the period),
which is what an IMU's anti-alias filter and integration deliver.

    imu = Imu(ImuParams())
    imu.reset(n=4, rate_hz=200.0, rng=np.random.default_rng(0))
    a_meas = imu(a_true, k)      # (4,) m/s^2 -> (4,) m/s^2
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError

__all__ = ["ImuParams", "Imu"]


@dataclass(frozen=True)
class ImuParams:
    """Accelerometer error model along one axis.

    Attributes
    ----------
    rate_hz : float
        Output rate, Hz (held between samples when slower than the controller).
    noise_std_mps2 : float
        White noise standard deviation per sample, m/s^2.
    bias_mps2 : float
        Constant bias, m/s^2.
    bias_walk_mps2_per_sqrt_s : float
        Random-walk intensity of the bias, m/s^2 per sqrt(s).
    """

    rate_hz: float = 200.0
    noise_std_mps2: float = 0.03
    bias_mps2: float = 0.05
    bias_walk_mps2_per_sqrt_s: float = 0.002

    def check(self) -> ImuParams:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise UserError(f"imu: rate_hz must be > 0, got {self.rate_hz}")
        for k in ("noise_std_mps2", "bias_walk_mps2_per_sqrt_s"):
            v = getattr(self, k)
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"imu: {k} must be >= 0, got {v}")
        if not math.isfinite(self.bias_mps2):
            raise UserError("imu: bias_mps2 must be finite")
        return self


class Imu:
    """``n`` accelerometers, one call per control sample."""

    def __init__(self, params: ImuParams):
        self.p = params.check()

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        """Start ``n`` episodes at controller rate ``rate_hz`` (Hz) drawing from ``rng``."""
        if self.p.rate_hz > rate_hz + 1e-9:
            raise UserError(f"imu: rate {self.p.rate_hz} Hz exceeds the control rate {rate_hz} Hz")
        self.n, self.rate_hz, self.rng = int(n), float(rate_hz), rng
        self.bias = np.full(self.n, float(self.p.bias_mps2))
        self.held = np.zeros(self.n)
        self.sample = -1

    def __call__(self, a_true: np.ndarray, k: int) -> np.ndarray:
        """Measured acceleration (n,) m/s^2 at control sample ``k`` from the true one (n,)."""
        s = int(math.floor(k * self.p.rate_hz / self.rate_hz + 1e-9))
        if s != self.sample:
            self.sample = s
            dt = 1.0 / self.p.rate_hz
            self.bias = self.bias + self.p.bias_walk_mps2_per_sqrt_s * math.sqrt(dt) * self.rng.standard_normal(self.n)
            noise = self.p.noise_std_mps2 * self.rng.standard_normal(self.n)
            self.held = np.asarray(a_true, dtype=np.float64) + self.bias + noise
        return self.held.copy()
