"""The sensor chain of a visual-servoing loop: camera, IMU, Kalman filter, low-pass.

One object per loop axis. Each control sample it takes the true position of
the vehicle relative to the target along the axis (m) and the true
acceleration (m/s^2), and gives what the controller sees:

- ``y_cam``: the camera's position (pinhole, frames, latency, pixels, noise),
  held between detections (IBVS, schedule 2);
- ``y_kf``: the time-synchronised Kalman estimate from the IMU and the
  camera (PBVS, schedule 1);

both through the vehicle's 2nd-order Butterworth at ``lowpass_hz`` (20 Hz on
the paper's vehicle), which the identification then sees as part of the loop.

The camera looks along ``s_x`` at a vertical target plane: the altitude loop
is the image's vertical axis (``o_y``), the lateral loop ``lateral_y`` its
horizontal axis (``o_x``).

    chain = SensorChain(ChainParams(camera=PRESETS["event"], axis="altitude"))
    chain.reset(n=1, rate_hz=200.0, rng=np.random.default_rng(0))
    s = chain(rel_true, acc_true, k)     # s.y_kf, s.y_cam, s.new_frame, s.innovation: (n,)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavsim.errors import UserError
from uavsim.model.effects import make_effect
from uavsim.vision.camera import CameraParams, CameraSensor
from uavsim.vision.imu import Imu, ImuParams
from uavsim.vision.kalman import AxisKalman, KalmanParams

__all__ = ["ChainParams", "ChainSample", "SensorChain", "AXES"]

#: image axis measured by each loop: column of ``[c_y, c_z]``
AXES = {"altitude": 1, "lateral_y": 0}


@dataclass(frozen=True)
class ChainParams:
    """Sensors of one loop axis.

    Attributes
    ----------
    camera : CameraParams
    axis : str
        ``altitude`` or ``lateral_y``.
    imu : ImuParams
    kalman : KalmanParams or None
        ``None``: derive ``sigma_c_m`` from the camera's pixel size and noise.
    lowpass_hz : float
        Vehicle measurement low-pass cut-off, Hz (0: none).
    """

    camera: CameraParams
    axis: str = "altitude"
    imu: ImuParams = field(default_factory=ImuParams)
    kalman: KalmanParams | None = None
    lowpass_hz: float = 20.0

    def check(self) -> ChainParams:
        if self.axis not in AXES:
            raise UserError(f"sensor chain: axis must be one of {', '.join(AXES)}, got {self.axis!r}")
        if not self.lowpass_hz >= 0:
            raise UserError(f"sensor chain: lowpass_hz must be >= 0, got {self.lowpass_hz}")
        self.camera.check()
        self.imu.check()
        return self

    def kalman_params(self) -> KalmanParams:
        if self.kalman is not None:
            return self.kalman
        c = self.camera
        # camera std on the target plane: detection noise plus the uniform
        # rounding error of one quantization step (variance q^2 / 12)
        px2 = c.noise_px**2 + c.quantization_px**2 / 12.0 + c.pattern_px**2 / 2.0
        return KalmanParams(sigma_c_m=float(np.sqrt(px2)) * c.metres_per_px, sigma_p_mps2=0.3 + 3 * self.imu.noise_std_mps2)


@dataclass
class ChainSample:
    """One control sample of the chain; arrays (n,)."""

    y_cam: np.ndarray
    y_kf: np.ndarray
    new_frame: np.ndarray
    lost: np.ndarray
    innovation: np.ndarray
    innovation_std: np.ndarray
    y_cam_raw: np.ndarray


class SensorChain:
    """Camera + IMU + Kalman filter + low-pass for ``n`` episodes."""

    def __init__(self, params: ChainParams):
        self.p = params.check()
        self.col = AXES[self.p.axis]
        self.camera = CameraSensor(self.p.camera)
        self.imu = Imu(self.p.imu)

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        """Start ``n`` episodes at control rate ``rate_hz`` Hz drawing from ``rng``."""
        self.n, self.rate_hz = int(n), float(rate_hz)
        self.camera.reset(n, rate_hz, rng)
        self.imu.reset(n, rate_hz, rng)
        history = int(np.ceil(self.p.camera.latency_s * rate_hz)) + int(np.ceil(rate_hz / self.p.camera.rate_hz)) + 8
        self.kf = AxisKalman(self.p.kalman_params(), rate_hz, n, history=history)
        self.lp_cam = self.lp_kf = None
        if self.p.lowpass_hz > 0:
            self.lp_cam = make_effect("lowpass", cutoff_hz=self.p.lowpass_hz)
            self.lp_kf = make_effect("lowpass", cutoff_hz=self.p.lowpass_hz)
            self.lp_cam.reset(n, rate_hz, rng)
            self.lp_kf.reset(n, rate_hz, rng)
        self.k0 = None

    def camera_frame(self, rel: np.ndarray) -> np.ndarray:
        """Target centre in the camera frame (n, 3) m for the vehicle at ``rel`` (n,) m from the target."""
        c = np.zeros((self.n, 3))
        c[:, 0] = self.p.camera.distance_m
        # the target is at -rel from the vehicle along the image axis
        c[:, 1 + self.col] = -np.asarray(rel, dtype=np.float64)
        return c

    def __call__(self, rel_true: np.ndarray, acc_true: np.ndarray, k: int) -> ChainSample:
        """Advance sample ``k`` with the true relative position (n,) m and acceleration (n,) m/s^2."""
        rel_true = np.asarray(rel_true, dtype=np.float64)
        a_meas = self.imu(acc_true, k)
        if self.k0 is None:
            self.k0 = k
            self.kf.reset(rel_true.copy())
        p_hat = self.kf.predict(a_meas)
        meas, new, lost = self.camera(self.camera_frame(rel_true), k)
        y_cam = -meas[:, self.col]
        nu = np.zeros(self.n)
        if new.any():
            # detections carry their capture sample: the filter corrects there
            # and replays the IMU (time synchronisation)
            nu = self.kf.correct(y_cam, self.camera.capture_k, new)
            p_hat = self.kf.x[:, 0].copy()
        y_c = self.lp_cam(y_cam, k) if self.lp_cam is not None else y_cam
        y_k = self.lp_kf(p_hat, k) if self.lp_kf is not None else p_hat
        return ChainSample(y_c, y_k, new, lost, nu, self.kf.innovation_std.copy(), y_cam)
