"""Vision sensors for visual servoing: camera, IMU, Kalman filter, schedules.

A camera (``camera``) looks at a planar target and reports the target centre
in pixels; the position is recovered with the pinhole model and the known
depth (paper eq. 2-3), at the camera's frame rate, after its latency, to its
pixel resolution and with its detection noise (presets ``normal``,
``event``, ``thermal``). An IMU (``imu``) gives the acceleration at 200 Hz with
noise and bias. A Kalman filter per axis (``kalman``, state ``[p, v, a_b]``)
fuses both, synchronised to the camera's capture times. ``chain`` puts them
together for one loop axis; ``schedules`` holds the PBVS (KF) and IBVS
(camera only) PD schedules and the switch on a large KF prediction error.

    from uavsim.vision import PRESETS, ChainParams, SensorChain
    chain = SensorChain(ChainParams(camera=PRESETS["normal"], axis="altitude"))
    chain.reset(n=1, rate_hz=200.0, rng=np.random.default_rng(0))
    s = chain(rel_true, acc_true, k)      # s.y_kf (PBVS), s.y_cam (IBVS)
"""

from uavsim.vision.camera import (
    PRESETS,
    CameraParams,
    CameraSensor,
    camera_preset,
    project,
    recover,
)
from uavsim.vision.chain import ChainParams, ChainSample, SensorChain
from uavsim.vision.imu import Imu, ImuParams
from uavsim.vision.kalman import AxisKalman, KalmanParams
from uavsim.vision.schedules import Schedule, ScheduledPD, ScheduleSwitch, SwitchParams

__all__ = [
    "PRESETS", "CameraParams", "CameraSensor", "camera_preset", "project", "recover",
    "ChainParams", "ChainSample", "SensorChain", "Imu", "ImuParams", "AxisKalman", "KalmanParams",
    "Schedule", "ScheduledPD", "ScheduleSwitch", "SwitchParams",
]
