"""Kalman filter per inertial axis, state ``[p, v, a_b]`` (paper section II-C).

Prediction with the accelerometer ``u`` (inertial frame) as the input, exactly
the paper's model (``Delta t`` is the control period):

    x_{k+1} = [[1, dt, -dt^2], [0, 1, -dt], [0, 0, 1]] x_k + [dt^2, dt, 0] u_k + w_k

``a_b`` is the accelerometer bias the filter learns from the camera. The
correction uses the camera position ``z = p + v_c``. Camera detections arrive
``latency`` samples after their capture; the filter is *time-synchronised*
(the paper's ``message_filters`` step, which it found the most important
calibration): the correction is applied at the capture sample, to the state
stored then, and the stored accelerometer inputs are replayed up to now. So
the camera's latency does not enter the estimate, only the IMU does.

The innovation ``z - p_pred`` of each correction is kept: a target that moves
makes it large (the IMU did not see that motion), which is what switches the
controller schedule (``uavsim.vision.schedules``).

    kf = AxisKalman(KalmanParams(), rate_hz=200.0, n=4, history=16)
    kf.reset(p0=np.zeros(4))
    p_hat = kf.predict(a_meas)                                   # (4,) every control sample
    kf.correct(z, capture_k, mask)                               # when a camera frame arrives
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError

__all__ = ["KalmanParams", "AxisKalman", "transition"]


@dataclass(frozen=True)
class KalmanParams:
    """Noise settings of the filter.

    Attributes
    ----------
    sigma_p_mps2 : float
        Std of the accelerometer input noise (process noise), m/s^2.
    sigma_c_m : float
        Std of the camera position measurement, m.
    sigma_bias_mps2_per_sqrt_s : float
        Random-walk intensity of the bias state, m/s^2 per sqrt(s).
    p0_var_m2, v0_var_m2ps2, b0_var_m2ps4 : float
        Initial variances of p (m^2), v ((m/s)^2), a_b ((m/s^2)^2).
    """

    sigma_p_mps2: float = 0.05
    sigma_c_m: float = 0.005
    sigma_bias_mps2_per_sqrt_s: float = 0.01
    p0_var_m2: float = 0.01
    v0_var_m2ps2: float = 0.01
    b0_var_m2ps4: float = 0.04

    def check(self) -> KalmanParams:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"kalman: {k} must be >= 0, got {v}")
        if self.sigma_c_m <= 0:
            raise UserError("kalman: sigma_c_m must be > 0")
        return self


def transition(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's ``F`` (3, 3) and input vector ``B`` (3,) for step ``dt`` s."""
    F = np.array([[1.0, dt, -dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
    B = np.array([dt * dt, dt, 0.0])
    return F, B


class AxisKalman:
    """``n`` independent filters along one axis, with delayed-measurement replay.

    Parameters
    ----------
    params : KalmanParams
    rate_hz : float
        Prediction (control) rate, Hz.
    n : int
        Episodes.
    history : int
        Samples of state kept for replay; must exceed the camera latency in samples.
    """

    def __init__(self, params: KalmanParams, rate_hz: float, n: int, history: int = 64):
        self.p = params.check()
        self.dt = 1.0 / float(rate_hz)
        self.n = int(n)
        self.H = int(history)
        if self.H < 2:
            raise UserError("kalman: history must be >= 2 samples")
        self.F, self.B = transition(self.dt)
        q = self.p.sigma_p_mps2**2 * np.outer(self.B, self.B)
        q[2, 2] += self.p.sigma_bias_mps2_per_sqrt_s**2 * self.dt
        self.Q = q
        self.R = self.p.sigma_c_m**2
        self.reset(np.zeros(self.n))

    def reset(self, p0: np.ndarray, v0: np.ndarray | None = None, b0: np.ndarray | None = None) -> None:
        """Start at position ``p0`` (n,) m (velocity ``v0``, bias ``b0``: 0 by default)."""
        n = self.n
        self.x = np.zeros((n, 3))
        self.x[:, 0] = p0
        if v0 is not None:
            self.x[:, 1] = v0
        if b0 is not None:
            self.x[:, 2] = b0
        self.P = np.tile(np.diag([self.p.p0_var_m2, self.p.v0_var_m2ps2, self.p.b0_var_m2ps4]), (n, 1, 1))
        self.k = -1
        self.hx = np.zeros((self.H, n, 3))
        self.hP = np.zeros((self.H, n, 3, 3))
        self.hu = np.zeros((self.H, n))
        self.innovation = np.zeros(n)
        self.innovation_std = np.full(n, math.sqrt(self.p.p0_var_m2 + self.R))

    def _step(self, x: np.ndarray, P: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = x @ self.F.T + u[:, None] * self.B[None, :]
        P = np.einsum("ij,njk,lk->nil", self.F, P, self.F) + self.Q
        return x, P

    def predict(self, u: np.ndarray) -> np.ndarray:
        """Advance one control sample with the accelerometer ``u`` (n,) m/s^2; return p (n,) m."""
        u = np.asarray(u, dtype=np.float64)
        self.k += 1
        if self.k > 0:
            self.x, self.P = self._step(self.x, self.P, u)
        i = self.k % self.H
        self.hx[i], self.hP[i], self.hu[i] = self.x, self.P, u
        return self.x[:, 0].copy()

    def correct(self, z: np.ndarray, capture_k: np.ndarray | int, mask: np.ndarray | None = None) -> np.ndarray:
        """Correct with camera positions ``z`` (n,) m captured at sample(s) ``capture_k``.

        Episodes outside ``mask`` (n,) bool are left alone. Returns the
        innovation (n,) m of the corrected episodes (0 elsewhere).
        """
        z = np.asarray(z, dtype=np.float64)
        mask = np.ones(self.n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        kc = np.broadcast_to(np.asarray(capture_k, dtype=np.int64), (self.n,))
        nu = np.zeros(self.n)
        for c in np.unique(kc[mask]):
            sel = mask & (kc == c)
            lag = self.k - int(c)
            if lag < 0:
                raise UserError("kalman: a measurement from the future")
            if lag >= self.H:
                raise UserError(f"kalman: measurement {lag} samples old exceeds the history of {self.H}")
            i = int(c) % self.H
            x, P = self.hx[i][sel].copy(), self.hP[i][sel].copy()
            S = P[:, 0, 0] + self.R
            Kg = P[:, :, 0] / S[:, None]
            v = z[sel] - x[:, 0]
            x = x + Kg * v[:, None]
            P = P - Kg[:, :, None] * P[:, 0, None, :]
            nu[sel] = v
            self.innovation_std[sel] = np.sqrt(S)
            self.hx[i][sel], self.hP[i][sel] = x, P
            # replay the stored accelerometer inputs from the capture sample to now
            for j in range(int(c) + 1, self.k + 1):
                ij = j % self.H
                x, P = self._step(x, P, self.hu[ij][sel])
                self.hx[ij][sel], self.hP[ij][sel] = x, P
            self.x[sel], self.P[sel] = x, P
        self.innovation = np.where(mask, nu, 0.0)
        return self.innovation.copy()

    def reposition(self, p: np.ndarray, mask: np.ndarray) -> None:
        """Move the position of the ``mask`` episodes to ``p`` (n,) m, keeping v and a_b.

        After the target jumped, the vehicle's velocity and the accelerometer
        bias are still right; only the position relative to the target is not.
        The stored history is shifted by the same amount so that late
        measurements replay consistently.
        """
        mask = np.asarray(mask, dtype=bool)
        d = np.where(mask, np.asarray(p, dtype=np.float64) - self.x[:, 0], 0.0)
        self.x[:, 0] += d
        self.hx[:, :, 0] += d[None, :]
