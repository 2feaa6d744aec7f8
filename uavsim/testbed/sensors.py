"""What the testbed's autopilot measures: an IMU with frame vibration, an attitude filter, a camera and a Kalman filter.

All sensors run at the physics rate (1 kHz) and none of them is Gaussian:

- **IMU** (MPU-6000 class): MuJoCo's gyro and accelerometer at the IMU site,
  plus frame vibration at the rotor frequencies (each rotor's imbalance, at
  its own phase ``integral w_i dt``, amplitude growing with ``w_i^2``, and a
  smaller blade-pass component at twice that), a constant bias, Student-t
  (heavy-tailed) white noise, quantization to the ADC's LSB, and the chip's
  2nd-order digital low-pass (DLPF).
- **Attitude filter**: quaternion integration of the gyro with a
  complementary (Mahony) correction toward the accelerometer's "up". On a
  multirotor the accelerometer reads the thrust direction, not gravity, so
  the correction pulls the estimate toward level: the real filter's small
  low-frequency error. Roll and pitch (ZYX Euler) are the attitude loops'
  measurement.
- **Camera** looking at a vertical target ``distance_m`` away: frames at
  ``rate_hz`` with timing jitter, dropped frames in bursts (a two-state
  chain), a latency, vertical position from the pixel centre (sub-pixel
  quantization, Student-t detection noise, rare outliers) and the frame's
  pitch vibration times the distance.
- **Altitude filter**: the project's time-synchronised Kalman filter
  (``uavsim.vision.kalman.AxisKalman``, state p, v, accelerometer bias) at the
  physics rate, predicted with the IMU's vertical specific force (rotated by
  the *estimated* attitude) and corrected by the camera at each frame's
  capture step.

    imu = Imu(ImuParams(), rng, w_hover=550.0)
    gyro, acc = imu(gyro_true, acc_true, phase, w)        # (3,), (3,)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.testbed.airframe import G
from uavsim.testbed.filters import Biquad
from uavsim.vision.kalman import AxisKalman, KalmanParams

__all__ = ["ImuParams", "Imu", "AttitudeFilter", "CameraParams", "Camera", "AltitudeFilter", "euler_rp"]


@dataclass(frozen=True)
class ImuParams:
    """IMU error model.

    Attributes
    ----------
    gyro_noise_rad_s, accel_noise_mps2 : float
        Scale of the Student-t white noise per 1 kHz sample.
    noise_dof : float
        Degrees of freedom of the Student-t noise (small: heavy tails).
    gyro_bias_rad_s, accel_bias_mps2 : float
        Largest constant bias per axis (drawn in +-this at reset).
    gyro_vib_rad_s, accel_vib_mps2 : float
        Vibration amplitude at hover rotor speed (sum over rotors, per axis).
    blade_pass_ratio : float
        Amplitude of the 2-per-revolution component relative to the 1-per-revolution one.
    gyro_lsb_rad_s, accel_lsb_mps2 : float
        ADC resolution.
    dlpf_hz : float
        Cut-off of the chip's 2nd-order low-pass on both sensors, Hz.
    """

    gyro_noise_rad_s: float = 0.004
    accel_noise_mps2: float = 0.05
    noise_dof: float = 4.0
    gyro_bias_rad_s: float = 0.001
    accel_bias_mps2: float = 0.05
    gyro_vib_rad_s: float = 0.02
    accel_vib_mps2: float = 1.0
    blade_pass_ratio: float = 0.4
    gyro_lsb_rad_s: float = 0.00106
    accel_lsb_mps2: float = 0.0048
    dlpf_hz: float = 98.0

    def check(self) -> ImuParams:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"imu: {k} must be >= 0, got {v}")
        if self.noise_dof <= 2 or self.dlpf_hz <= 0:
            raise UserError("imu: need noise_dof > 2 and dlpf_hz > 0")
        return self


def _quantize(x: np.ndarray, lsb: float) -> np.ndarray:
    return np.round(x / lsb) * lsb if lsb > 0 else x


class Imu:
    """Gyro and accelerometer of one vehicle, sampled once per physics step."""

    def __init__(self, params: ImuParams, rng: np.random.Generator, w_hover: float, rate_hz: float = 1000.0):
        self.p = params.check()
        self.rng = rng
        self.w_hover = float(w_hover)
        p = self.p
        self.gyro_bias = rng.uniform(-1, 1, 3) * p.gyro_bias_rad_s
        self.accel_bias = rng.uniform(-1, 1, 3) * p.accel_bias_mps2

        def mix(amp: float) -> np.ndarray:
            # (6 rotors, 2 quadratures, 3 axes): each rotor shakes the frame its own way
            m = rng.normal(size=(6, 2, 3))
            return amp * m / math.sqrt(np.sum(m * m) / 3.0)

        self.gyro_mix, self.accel_mix = mix(p.gyro_vib_rad_s), mix(p.accel_vib_mps2)
        self.blade_phase = rng.uniform(0, 2 * math.pi, 6)
        self.lp_gyro = Biquad.butter_lowpass(p.dlpf_hz, rate_hz, (3,))
        self.lp_accel = Biquad.butter_lowpass(p.dlpf_hz, rate_hz, (3,))
        self.lp_accel.prime(np.array([0.0, 0.0, G]))

    def vibration(self, phase: np.ndarray, w: np.ndarray, mix: np.ndarray) -> np.ndarray:
        """(3,) vibration from the rotors at phases ``phase`` (6,) rad and speeds ``w`` (6,) rad/s."""
        r2 = (w / self.w_hover) ** 2
        c, s = np.cos(phase), np.sin(phase)
        one = (r2 * c) @ mix[:, 0] + (r2 * s) @ mix[:, 1]
        two = (r2 * np.cos(2 * phase + self.blade_phase)) @ mix[:, 0]
        return one + self.p.blade_pass_ratio * two

    def __call__(self, gyro_true: np.ndarray, accel_true: np.ndarray, phase: np.ndarray,
                 w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p, rng = self.p, self.rng
        g = gyro_true + self.gyro_bias + self.vibration(phase, w, self.gyro_mix)
        g = g + p.gyro_noise_rad_s * rng.standard_t(p.noise_dof, 3)
        a = accel_true + self.accel_bias + self.vibration(phase, w, self.accel_mix)
        a = a + p.accel_noise_mps2 * rng.standard_t(p.noise_dof, 3)
        return self.lp_gyro(_quantize(g, p.gyro_lsb_rad_s)), self.lp_accel(_quantize(a, p.accel_lsb_mps2))


def euler_rp(q: np.ndarray) -> tuple[float, float]:
    """Roll and pitch (ZYX Euler angles), rad, of the unit quaternion ``q`` = (w, x, y, z)."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3), body to world, of ``q`` = (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


class AttitudeFilter:
    """Mahony complementary filter (proportional only) at the physics rate.

    Parameters
    ----------
    k_acc_per_s : float
        Gain of the correction toward the accelerometer's "up", 1/s.
    dt_s : float
    q0 : (4,) initial quaternion (the true one: the filter has converged on the ground)
    """

    def __init__(self, k_acc_per_s: float, dt_s: float, q0: np.ndarray):
        self.k = float(k_acc_per_s)
        self.dt = float(dt_s)
        self.q = np.array(q0, dtype=np.float64)

    def __call__(self, gyro: np.ndarray, accel: np.ndarray) -> np.ndarray:
        w, x, y, z = self.q
        # "up" in the body frame as the estimate has it: third row of R
        up = np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
        n = math.sqrt(float(accel @ accel))
        e = np.cross(accel / n, up) if n > 1e-6 else np.zeros(3)
        om = gyro + self.k * e
        dq = 0.5 * np.array([
            -x * om[0] - y * om[1] - z * om[2],
            w * om[0] + y * om[2] - z * om[1],
            w * om[1] - x * om[2] + z * om[0],
            w * om[2] + x * om[1] - y * om[0],
        ])  # fmt: skip
        q = self.q + self.dt * dq
        self.q = q / math.sqrt(float(q @ q))
        return self.q


@dataclass(frozen=True)
class CameraParams:
    """Camera timing and detection quality.

    Attributes
    ----------
    rate_hz : float
        Nominal frame rate, Hz.
    jitter_s : float
        Standard deviation of each frame interval's timing error, s.
    drop_prob : float
        Probability that a frame starts a drop burst.
    drop_stay : float
        Probability that the frame after a dropped one is dropped too.
    latency_s : float
        Capture-to-controller latency, s.
    focal_px : float
    distance_m : float
        Depth of the target, m (known).
    quant_px : float
        Resolution of the detected centre, px.
    noise_px : float
        Scale of the Student-t detection noise, px.
    noise_dof : float
    outlier_prob : float
        Probability of a gross detection error.
    outlier_px : float
        Scale of a gross error, px.
    vib_rad : float
        Frame pitch vibration at hover rotor speed seen by the camera, rad.
    """

    rate_hz: float = 60.0
    jitter_s: float = 0.002
    drop_prob: float = 0.03
    drop_stay: float = 0.4
    latency_s: float = 0.03
    focal_px: float = 615.0
    distance_m: float = 3.0
    quant_px: float = 0.25
    noise_px: float = 0.3
    noise_dof: float = 3.0
    outlier_prob: float = 0.005
    outlier_px: float = 4.0
    vib_rad: float = 4e-4

    def check(self) -> CameraParams:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"camera: {k} must be >= 0, got {v}")
        if self.rate_hz <= 0 or self.focal_px <= 0 or self.distance_m <= 0 or self.noise_dof <= 2:
            raise UserError("camera: need rate_hz, focal_px, distance_m > 0 and noise_dof > 2")
        if not (self.drop_prob < 1 and self.drop_stay < 1):
            raise UserError("camera: drop probabilities must be < 1")
        return self

    @property
    def metres_per_px(self) -> float:
        return self.distance_m / self.focal_px


class Camera:
    """Frames of the vertical position, delivered after their latency."""

    def __init__(self, params: CameraParams, rng: np.random.Generator, w_hover: float):
        self.p = params.check()
        self.rng = rng
        self.w_hover = float(w_hover)
        self.vib_mix = rng.normal(size=(6, 2))
        self.vib_mix *= self.p.vib_rad / math.sqrt(np.sum(self.vib_mix**2))
        self.next_capture = rng.uniform(0, 1.0 / self.p.rate_hz)
        self.dropping = False
        self.pending: list[tuple[float, float, int]] = []  # (arrival time, z, capture step)
        self.frames = 0
        self.dropped = 0

    def step(self, t: float, step: int, z_true: float, phase: np.ndarray, w: np.ndarray) -> list[tuple[float, int]]:
        """Capture if a frame is due at ``t``; return the detections ``(z, capture step)`` arriving now."""
        p, rng = self.p, self.rng
        if t + 1e-12 >= self.next_capture:
            self.next_capture += 1.0 / p.rate_hz + p.jitter_s * rng.standard_normal()
            self.next_capture = max(self.next_capture, t + 0.25 / p.rate_hz)
            self.frames += 1
            self.dropping = rng.random() < (p.drop_stay if self.dropping else p.drop_prob)
            if self.dropping:
                self.dropped += 1
            else:
                r2 = (w / self.w_hover) ** 2
                vib = float((r2 * np.cos(phase)) @ self.vib_mix[:, 0] + (r2 * np.sin(phase)) @ self.vib_mix[:, 1])
                px = p.focal_px * (z_true + p.distance_m * vib) / p.distance_m
                px += p.noise_px * rng.standard_t(p.noise_dof)
                if rng.random() < p.outlier_prob:
                    px += p.outlier_px * rng.standard_normal()
                if p.quant_px > 0:
                    px = round(px / p.quant_px) * p.quant_px
                self.pending.append((t + p.latency_s, px * p.metres_per_px, step))
        out = [(z, k) for (ta, z, k) in self.pending if ta <= t + 1e-12]
        if out:
            self.pending = [e for e in self.pending if e[0] > t + 1e-12]
        return out


class AltitudeFilter:
    """Camera + IMU Kalman filter on the vertical axis, one prediction per physics step."""

    def __init__(self, camera: CameraParams, imu: ImuParams, dt_s: float, z0: float):
        sigma_c = math.sqrt(camera.noise_px**2 * 3.0 + camera.quant_px**2 / 12.0) * camera.metres_per_px
        kp = KalmanParams(sigma_p_mps2=0.3 + 3 * imu.accel_noise_mps2 + imu.accel_vib_mps2, sigma_c_m=sigma_c)
        history = int(math.ceil((camera.latency_s + 0.02) / dt_s)) + 8
        self.kf = AxisKalman(kp, 1.0 / dt_s, 1, history=history)
        self.kf.reset(np.array([z0]))
        self.k = -1

    def predict(self, a_z: float) -> float:
        """Advance one step with the vertical specific force minus gravity ``a_z``, m/s^2; return p, m."""
        self.k += 1
        return float(self.kf.predict(np.array([a_z]))[0])

    def correct(self, z: float, capture_step: int) -> float:
        self.kf.correct(np.array([z]), capture_step)
        return float(self.kf.x[0, 0])
