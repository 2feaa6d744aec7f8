"""Pinhole camera sensor: geometry, quantization, frame timing, latency, field of view."""

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.vision.camera import (
    PRESETS,
    CameraParams,
    CameraSensor,
    camera_preset,
    project,
    recover,
)


def test_project_recover_roundtrip():
    cam = PRESETS["normal"]
    rng = np.random.default_rng(0)
    c = np.stack([np.full(50, 4.0), rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50)], axis=1)
    back = recover(cam, project(cam, c), c[:, 0])
    np.testing.assert_allclose(back, c[:, 1:], atol=1e-12)
    # image centre is the optical axis; one pixel is distance / focal on the target plane
    o = project(cam, np.array([[4.0, 0.0, cam.metres_per_px]]))
    np.testing.assert_allclose(o[0], [cam.cu_px, cam.cv_px + 1.0])


def test_quantization_error_bounded_without_noise():
    cam = camera_preset("normal", noise_px=0.0)
    s = CameraSensor(cam)
    s.reset(200, 200.0, np.random.default_rng(1))
    z = np.linspace(-0.5, 0.5, 200)
    c = np.stack([np.full(200, 4.0), np.zeros(200), z], axis=1)
    meas, lost = s.detect(c, 0.0)
    assert not lost.any()
    err = np.abs(meas[:, 1] - z)
    assert err.max() <= 0.5 * cam.metres_per_px + 1e-12
    assert err.max() > 0.3 * cam.metres_per_px  # it does quantize


@pytest.mark.parametrize("name", ["normal", "event", "thermal"])
def test_frame_rate_and_latency(name):
    cam = camera_preset(name, noise_px=0.0, pattern_px=0.0)
    s = CameraSensor(cam)
    rate = 200.0
    s.reset(1, rate, np.random.default_rng(2))
    k_step = 100
    news, first_seen = 0, None
    for k in range(400):
        z = 0.3 if k >= k_step else 0.0
        rel, new, _ = s(np.array([[4.0, 0.0, z]]), k)
        news += int(new[0])
        if first_seen is None and abs(rel[0, 1] - 0.3) < 0.01:
            first_seen = k
    assert abs(news - cam.rate_hz * 2.0) <= 2  # 2 s of frames
    delay_s = (first_seen - k_step) / rate
    # the step is seen after the latency plus at most one frame period
    assert cam.latency_s - 1 / rate <= delay_s <= cam.latency_s + 1 / cam.rate_hz + 1 / rate


def test_presets_ordering():
    n, e, t = PRESETS["normal"], PRESETS["event"], PRESETS["thermal"]
    assert e.rate_hz > n.rate_hz > t.rate_hz
    assert e.latency_s < n.latency_s < t.latency_s
    assert e.pattern_px > 0 and n.pattern_px == 0
    assert t.half_fov_m[1] < n.half_fov_m[1]  # thermal: limited field of view
    assert t.noise_px * t.metres_per_px > n.noise_px * n.metres_per_px


def test_event_pattern_noise_is_periodic():
    cam = camera_preset("event", noise_px=0.0, quantization_px=0.0)
    s = CameraSensor(cam)
    s.reset(1, 200.0, np.random.default_rng(3))
    ys = np.array([s.detect(np.array([[4.0, 0.0, 0.0]]), k / 100.0)[0][0, 1] for k in range(200)])
    amp = cam.pattern_px * cam.metres_per_px
    assert np.max(np.abs(ys)) == pytest.approx(amp, rel=0.05)
    spec = np.abs(np.fft.rfft(ys))
    f = np.fft.rfftfreq(ys.size, 1 / 100.0)
    assert f[np.argmax(spec)] == pytest.approx(cam.pattern_hz, abs=0.5)


def test_target_outside_fov_is_lost_and_held():
    cam = camera_preset("thermal", noise_px=0.0)
    s = CameraSensor(cam)
    s.reset(1, 200.0, np.random.default_rng(4))
    rel, _, _ = s(np.array([[4.0, 0.0, 0.1]]), 0)
    far = 2 * cam.half_fov_m[1]
    lost_any, news = False, 0
    for k in range(1, 60):
        rel, new, lost = s(np.array([[4.0, 0.0, far]]), k)
        lost_any |= bool(lost[0])
        news += int(new[0])
    assert lost_any
    assert news == 1  # only the frame captured in view (at k = 0) arrives
    assert rel[0, 1] == pytest.approx(0.1, abs=cam.metres_per_px)


def test_bad_parameters():
    with pytest.raises(UserError):
        camera_preset("infrared")
    with pytest.raises(UserError):
        camera_preset("normal", focal=3.0)
    with pytest.raises(UserError):
        CameraParams(rate_hz=0.0).check()
    s = CameraSensor(camera_preset("normal", rate_hz=250.0))
    with pytest.raises(UserError):
        s.reset(1, 200.0, np.random.default_rng(0))
