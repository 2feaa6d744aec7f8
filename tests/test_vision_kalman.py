"""Kalman filter [p, v, a_b], IMU, sensor chain: accuracy, bias, time synchronisation."""

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.vision.camera import PRESETS
from uavsim.vision.chain import ChainParams, SensorChain
from uavsim.vision.imu import Imu, ImuParams
from uavsim.vision.kalman import AxisKalman, KalmanParams, transition


def test_transition_is_the_papers():
    F, B = transition(0.005)
    np.testing.assert_allclose(F, [[1, 0.005, -0.005**2], [0, 1, -0.005], [0, 0, 1]])
    np.testing.assert_allclose(B, [0.005**2, 0.005, 0])


def _motion(T, rate):
    t = np.arange(T) / rate
    p = 0.3 * np.sin(2 * np.pi * 0.7 * t) + 0.1 * np.sin(2 * np.pi * 2.3 * t)
    a = -0.3 * (2 * np.pi * 0.7) ** 2 * np.sin(2 * np.pi * 0.7 * t) - 0.1 * (2 * np.pi * 2.3) ** 2 * np.sin(2 * np.pi * 2.3 * t)
    return t, p, a


@pytest.mark.parametrize("preset", ["normal", "event", "thermal"])
def test_chain_kf_beats_camera_and_learns_bias(preset):
    rate, T = 200.0, 4000
    t, p, a = _motion(T, rate)
    bias = 0.2
    chain = SensorChain(ChainParams(camera=PRESETS[preset], imu=ImuParams(bias_mps2=bias), lowpass_hz=0.0))
    chain.reset(1, rate, np.random.default_rng(5))
    ykf, ycam = np.zeros(T), np.zeros(T)
    for k in range(T):
        s = chain(np.array([p[k]]), np.array([a[k]]), k)
        ykf[k], ycam[k] = s.y_kf[0], s.y_cam[0]
    late = slice(T // 2, None)
    rms_kf = np.sqrt(np.mean((ykf[late] - p[late]) ** 2))
    rms_cam = np.sqrt(np.mean((ycam[late] - p[late]) ** 2))
    # the camera is late by its latency and holds frames; the synchronised KF is not
    assert rms_kf < 0.5 * rms_cam
    assert chain.kf.x[0, 2] == pytest.approx(bias, abs=0.08)


def test_delayed_measurement_replay_equals_on_time_correction():
    """A correction at its capture sample, replayed, equals the filter that had it on time."""
    rate = 200.0
    rng = np.random.default_rng(6)
    u = rng.normal(0, 1, 50)
    kp = KalmanParams()
    on_time = AxisKalman(kp, rate, 1)
    late = AxisKalman(kp, rate, 1)
    for k in range(50):
        on_time.predict(u[k:k + 1])
        late.predict(u[k:k + 1])
        if k == 20:
            on_time.correct(np.array([0.1]), 20)
        if k == 27:
            late.correct(np.array([0.1]), 20)
    np.testing.assert_allclose(late.x, on_time.x, atol=1e-12)
    np.testing.assert_allclose(late.P, on_time.P, atol=1e-12)
    with pytest.raises(UserError):
        late.correct(np.array([0.0]), 60)  # from the future


def test_imu_noise_and_bias():
    imu = Imu(ImuParams(noise_std_mps2=0.05, bias_mps2=0.1, bias_walk_mps2_per_sqrt_s=0.0))
    imu.reset(1, 200.0, np.random.default_rng(7))
    m = np.array([imu(np.zeros(1), k)[0] for k in range(4000)])
    assert m.mean() == pytest.approx(0.1, abs=0.005)
    assert m.std() == pytest.approx(0.05, rel=0.1)
    with pytest.raises(UserError):
        ImuParams(rate_hz=-1.0).check()


def test_reposition_keeps_velocity():
    kf = AxisKalman(KalmanParams(), 200.0, 2)
    kf.reset(np.zeros(2), v0=np.array([0.5, 0.5]))
    kf.predict(np.zeros(2))
    kf.reposition(np.array([1.0, 1.0]), np.array([True, False]))
    assert kf.x[0, 0] == 1.0 and kf.x[1, 0] != 1.0
    assert kf.x[0, 1] == pytest.approx(0.5)
