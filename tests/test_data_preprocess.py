"""Preprocessing against analytic relay cycles (an integrator under a relay: exact triangles)."""

import numpy as np
import pytest

from uavsim.data.preprocess import (
    INPUT_RATE_HZ,
    features,
    features_batch,
    input_length,
)
from uavsim.errors import NoOscillation


def relay_trace(period_s: float, rate_hz: float, duration_s: float, h: float = 1.0, bias: float = 0.0,
                duty: float = 0.5, k: float = 3.0, offset: float = 0.2):
    """u: relay square wave (+h for ``duty`` of each cycle, starting with -h), y: k * integral of (u - bias)
    shifted to zero mean over a cycle. Exact triangle: amplitude k h duty (1 - duty) period."""
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    phase = (t / period_s) % 1.0
    up = phase >= (1 - duty)
    s = np.where(up, 1.0, -1.0)
    u = h * s + bias
    y = np.cumsum(k * h * s) / rate_hz + offset
    return y, u


def test_triangle_period_amplitude_and_normalization():
    T0, rate = 0.5, 200.0
    y, u = relay_trace(T0, rate, 4.0)
    f = features(y, u, rate, 1.0, 0.0, L=160)
    assert f.period == pytest.approx(T0, abs=1e-12)
    # triangle of slope 3 over a half cycle of 0.25 s: peak-to-peak 0.75 (50 steps of 3/200)
    assert f.amplitude == pytest.approx(0.5 * 3.0 * T0 / 2, rel=1e-9)
    x = f.x
    assert x.shape == (2, 160) and x.dtype == np.float32
    n = int(T0 * rate)
    assert np.all(x[:, : 160 - n] == 0) and np.all(np.abs(x[1, 160 - n:]) == 1)
    assert x[0, 160 - n:].max() == pytest.approx(1.0) and x[0, 160 - n:].min() == pytest.approx(-1.0)
    # the segment starts at a rising edge of u and spans one cycle
    assert x[1, 160 - n] == 1 and f.stop - f.start == n and u[f.start] > 0 > u[f.start - 1]


def test_bias_and_h_normalized():
    y, u = relay_trace(0.4, 200.0, 4.0, h=0.3, bias=0.1, duty=0.3)
    f = features(y, u, 200.0, 0.3, 0.1, L=100)
    assert f.period == pytest.approx(0.4)
    seg = f.x[1, 100 - 80:]
    assert set(np.unique(seg)) == {-1.0, 1.0} and np.mean(seg > 0) == pytest.approx(0.3, abs=0.02)


def test_resampled_rate_matches_control_rate():
    T0 = 0.37
    y2, u2 = relay_trace(T0, 200.0, 4.0)
    y1, u1 = relay_trace(T0, 1000.0, 4.0)
    f2 = features(y2, u2, 200.0, 1.0, 0.0, L=100)
    f1 = features(y1, u1, 1000.0, 1.0, 0.0, L=100)
    # the period is timed at 1 kHz (5x finer), the input is built at 200 Hz
    assert abs(f1.period - T0) <= 1e-3 and abs(f2.period - T0) <= 1 / 200.0
    n1 = np.count_nonzero(f1.x[1])
    n2 = np.count_nonzero(f2.x[1])
    assert abs(n1 - n2) <= 1 and abs(n1 - T0 * INPUT_RATE_HZ) <= 1
    # start is an index of the 1 kHz trace, at its rising edge (within one 200 Hz sample)
    assert np.any(np.diff((u1[f1.start - 5:f1.start + 6] > 0).astype(int)) == 1)


@pytest.mark.parametrize("case, needle", [
    ("flat", "full relay cycles"), ("nan", "NaN"), ("short", "full relay cycles"), ("notrelay", "relay command"),
    ("chatter", "chatters"), ("long", "do not fit"), ("duty", "unsymmetric"), ("drift", "steady"),
])
def test_garbage_rejected(case, needle):
    y, u = relay_trace(0.5, 200.0, 4.0)
    L = 160
    if case == "flat":
        u = np.ones_like(u)
    elif case == "nan":
        y[100] = np.nan
    elif case == "short":
        y, u = y[:150], u[:150]
    elif case == "notrelay":
        u = u * 0.5
    elif case == "chatter":
        y, u = relay_trace(0.02, 200.0, 2.0)
    elif case == "long":
        L = 50
    elif case == "duty":
        y, u = relay_trace(0.75, 200.0, 6.0, duty=0.02)
        L = 400
    elif case == "drift":
        y1, u1 = relay_trace(0.5, 200.0, 3.0)
        y2, u2 = relay_trace(0.25, 200.0, 0.5)
        y, u = np.concatenate([y1, y2 + y1[-1]]), np.concatenate([u1, u2])
    with pytest.raises(NoOscillation, match=needle):
        features(y, u, 200.0, 1.0, 0.0, L)


def test_batch_flags_rows():
    y, u = relay_trace(0.5, 200.0, 4.0)
    Y = np.stack([y, y, y])
    U = np.stack([u, np.ones_like(u), u])
    X, P, A, ok = features_batch(Y, U, 200.0, np.ones(3), np.zeros(3), 160)
    assert ok.tolist() == [True, False, True] and np.all(X[1] == 0) and np.isnan(P[1]) and np.isnan(A[1])
    assert P[0] == pytest.approx(0.5) and np.array_equal(X[0], X[2])


def test_input_length_covers_grid():
    from uavsim.tuning.grid import load_grid

    g = load_grid("altitude")
    L = input_length(g)
    assert L % 8 == 0 and L >= 1.25 * g.period.max() * INPUT_RATE_HZ
    assert L < 1.25 * g.period.max() * INPUT_RATE_HZ + 8


def test_waveform_harmonics_of_a_known_signal():
    """Harmonics at a non-integer period (37.3 samples) under a DC offset and a drift, against
    the amplitudes the signal was built from; a per-cycle DFT over whole samples leaks."""
    from uavsim.data.preprocess import waveform_harmonics
    from uavsim.noise.analysis import cycle_harmonics

    N, cycles = 37.3, 5
    n = np.arange(int(N * (cycles + 1)))
    true = np.array([1.0, 0.0, 0.03 * np.exp(-1.1j), 0.0, 0.01 * np.exp(2.0j), 0.0, 0.004j])
    x = 0.7 + 0.002 * n + sum((X * np.exp(2j * np.pi * (k + 1) * n / N)).real * 2 for k, X in enumerate(true))
    start, stop = 10, 10 + int(round(N * cycles))
    hx2, hu = waveform_harmonics(np.stack([x, -x]), start, stop, N)
    np.testing.assert_allclose(hx2, true, atol=1e-9)
    np.testing.assert_allclose(hu, -true, atol=1e-9)
    edges = np.round(start + N * np.arange(cycles + 1)).astype(int)
    leak = cycle_harmonics(x, edges, (3,))[0]
    assert abs(leak - true[2]) > 0.1 * abs(true[2])


def test_waveform_harmonics_stop_below_nyquist():
    """Short cycles: harmonics at or above 0.8 Nyquist are NaN, not a singular solve."""
    from uavsim.data.preprocess import waveform_harmonics

    u = np.tile(np.r_[np.ones(4), -np.ones(4)], 6)  # 8-sample cycles: the 4th harmonic is Nyquist
    (hu,) = waveform_harmonics(u, 8, 48, 8.0)
    assert np.all(np.isfinite(hu[:3])) and np.all(np.isnan(hu[3:]))
    assert abs(hu[0]) > 0.5 and abs(hu[1]) < 1e-12  # a square wave has no even harmonics
    (h4,) = waveform_harmonics(u, 8, 16, 4.0)  # 4-sample cycles: the fundamental only
    assert np.isfinite(h4[0]) and np.all(np.isnan(h4[1:]))
