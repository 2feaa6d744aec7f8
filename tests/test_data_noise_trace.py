"""Precomputed noise traces against the per-sample study models (same statistics)."""

import numpy as np
import pytest
from scipy import signal

from uavsim.data.noise_trace import NoiseTrace
from uavsim.noise.models import make_noise

RATE = 200.0
N, T = 64, 4000


def _run(eff, n=N, T=T, seed=0):
    eff.reset(n, RATE, np.random.default_rng(seed))
    return np.stack([eff(np.zeros(n), k) for k in range(T)])


@pytest.mark.parametrize("kind", ["white", "paper", "coloured", "outliers"])
def test_trace_matches_per_sample_model(kind):
    amp = np.linspace(0.5, 2.0, N)
    ref = _run(make_noise(kind, 1.0, amp))
    tr = _run(NoiseTrace(groups=[(np.arange(N), make_noise(kind, 1.0, amp))], samples=T))
    # std over all episodes, and per episode (proportional to amp; sparse spikes vary more)
    assert (tr / amp).std() == pytest.approx((ref / amp).std(), rel=0.06)
    np.testing.assert_allclose(tr.std(axis=0) / amp, ref.std(axis=0) / amp, rtol=0.4 if kind == "outliers" else 0.15)
    assert abs(tr.mean()) < 0.05 and abs(ref.mean()) < 0.05
    # same spectrum shape: power in the lower and upper halves of the band
    f, p_ref = signal.welch(ref / amp, fs=RATE, axis=0, nperseg=256)
    _, p_tr = signal.welch(tr / amp, fs=RATE, axis=0, nperseg=256)
    lo = f < RATE / 4
    for part in (lo, ~lo):
        assert p_tr[part].mean() == pytest.approx(p_ref[part].mean(), rel=0.25)


def test_quantization_and_clean_groups():
    eff = NoiseTrace(groups=[(np.array([0, 1]), make_noise("quantization", 1.0, np.array([0.1, 0.2]))),
                             (np.array([2]), None)], samples=10)
    eff.reset(4, RATE, np.random.default_rng(0))
    x = np.array([0.26, 0.26, 0.26, 0.26])
    np.testing.assert_allclose(eff(x, 3), [0.3, 0.2, 0.26, 0.26])
    # beyond the precomputed length: clean but still quantized
    np.testing.assert_allclose(eff(x, 50), [0.3, 0.2, 0.26, 0.26])


def test_same_seed_same_trace():
    def mk():
        return NoiseTrace(groups=[(np.arange(4), make_noise("coloured", 1.0, np.ones(4)))], samples=100)

    np.testing.assert_array_equal(_run(mk(), 4, 100, 3), _run(mk(), 4, 100, 3))
