"""The gap workflow's per-episode effects equal the registry effects, sample by sample."""

import numpy as np
import pytest

from uavsim.gap.vector_effects import batch_effects
from uavsim.model.effects import make_effect

RATE = 200.0
CASES = [
    ("lag", {"T": 0.05}),
    ("rate_limit", {"rate": 30.0}),
    ("dead_zone", {"width": 0.3}),
    ("saturation", {"limit": 0.6}),
    ("bias", {"offset": -0.2}),
    ("quantization", {"step": 0.07}),
    ("sample_hold", {"rate_hz": 60.0}),
    ("sample_hold", {"rate_hz": 100.0}),
    ("lowpass", {"cutoff_hz": 12.0}),
]


@pytest.mark.parametrize(("name", "params"), CASES)
def test_vector_effect_matches_registry(name, params):
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.standard_normal((300, 3)), axis=0) * 0.1  # three episodes, 300 samples
    ref = make_effect(name, **params)
    ref.reset(3, RATE, np.random.default_rng(0))
    value = next(iter(params.values()))
    # episode 1 has the effect, episodes 0 and 2 are identity
    fx = batch_effects(["none", name, "none"], [0.0, value, 0.0], 0.0, RATE)
    chain = [e for e in fx if e.target == ref.target][0]
    chain.reset(3, RATE, np.random.default_rng(0))
    for k in range(x.shape[0]):
        want = ref(x[k].copy(), k)
        got = chain(x[k].copy(), k)
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got[[0, 2]], x[k, [0, 2]], rtol=1e-12, atol=1e-12)


def test_model_effects_are_per_episode():
    fx = batch_effects(["delay", "gain", "none"], [0.02, 1.5, 0.0], 0.001, RATE)
    by = {e.name: e for e in fx}
    np.testing.assert_array_equal(by["delay"].delay, [0.02, 0.0, 0.0])
    np.testing.assert_array_equal(by["gain"].factor, [1.0, 1.5, 1.0])


def test_noise_level_adds_in_quadrature():
    fx = batch_effects(["noise", "none"], [0.004, 0.0], 0.003, RATE)
    meas = [e for e in fx if e.target == "measurement"][0]
    np.testing.assert_allclose(meas.std, [0.005, 0.003])
    meas.reset(2, RATE, np.random.default_rng(3))
    y = np.array([meas(np.zeros(2), k) for k in range(20000)])
    np.testing.assert_allclose(y.std(axis=0), [0.005, 0.003], rtol=0.03)
