"""The fused NP-MRFT update is the unfused one, bit for bit, in every state and output.

``tests/_relay_reference.py`` keeps the per-sample update as it was before its
numpy operations were fused; both relays are fed the same error sequences and
compared after every sample: the command, ``switched``, ``confirmed``,
``armed``, ``guard`` and the whole internal state. The sequences are the hard
cases: noisy cycles (noise switches a relay early and moves its extremum),
quantized plateaus (ties), an offset cycle with relay bias (the centre), a
cycle that stops crossing (the deadlock guard), non-finite errors, retuning in
the middle of a run, both readings, MRFT, and a restart (``reset``).
"""

import numpy as np
import pytest
from _relay_reference import ReferenceNPMRFT

from uavsim.control.relay import MRFT, NPMRFT

STATE = ("sign", "e_ext", "k_ext", "k_sw", "k_sw2", "k_sw3", "half", "n_sw", "sum_e", "sum_sw", "sum_sw2", "sum_sw3",
         "_centre", "armed", "guard", "switched", "confirmed", "n_obs", "k")


def errors(rng: np.random.Generator, n: int, T: int, *, quant: bool, stall: bool, bad: bool) -> np.ndarray:
    """(T, n) errors: cycles of random periods, phases, offsets and noise."""
    t = np.arange(T)[:, None]
    period = rng.uniform(8, 120, n)
    e = rng.uniform(0.2, 2.0, n) * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi, n))
    e += rng.uniform(-0.8, 0.8, n) * (rng.random(n) < 0.5)  # offset cycles: the bias centre
    e += rng.uniform(0, 0.3, n) * rng.standard_normal((T, n)) * (rng.random(n) < 0.7)
    if quant:
        step = rng.uniform(0.05, 0.4, n)
        e = step * np.round(e / step)
    if stall:
        e[T // 2:, : n // 3] = np.abs(e[T // 2:, : n // 3]) + 0.5  # no more crossings: the guard acts
    if bad:
        e[rng.integers(0, T, 3), rng.integers(0, n, 3)] = [np.nan, np.inf, -np.inf]
    e[:, 0] = 0.0  # exact zeros and ties everywhere
    return e


def assert_same(a, b, k):
    for name in STATE:
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(x, y, equal_nan=True), f"{name} differs at sample {k}: {x} {y}"


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("reading", [1, 2])
@pytest.mark.parametrize("kind", ["npmrft", "mrft"])
def test_fused_update_matches_reference(seed, reading, kind):
    rng = np.random.default_rng([seed, reading])
    n, T = 24, 700
    bias = rng.uniform(-0.6, 0.6, n) * (rng.random(n) < 0.6) if seed % 2 else 0.0
    beta = rng.uniform(-0.9, 0.5, n)
    h = rng.uniform(0.2, 2.0, n)
    tau_obs, a_n = rng.uniform(0, 0.1, n), rng.uniform(0, 0.2, n)
    if kind == "mrft":
        a, b = (cls(beta, h, 200.0, n, bias=bias, reading=reading) for cls in (MRFT, _ref_mrft))
    else:
        a, b = (cls(beta, h, tau_obs, a_n, 200.0, n, bias=bias, reading=reading) for cls in (NPMRFT, ReferenceNPMRFT))
    E = errors(rng, n, T, quant=seed % 3 == 1, stall=seed % 3 == 2, bad=seed == 5)
    with np.errstate(invalid="ignore"):
        for k in range(T):
            if k == T // 3 and kind == "npmrft":
                tau2, an2 = rng.uniform(0, 0.1, n), rng.uniform(0, 0.2, n)
                a.retune(tau2, an2)
                b.retune(tau2, an2)
            if k == 2 * T // 3:
                a.reset()
                b.reset()
            ua, ub = a(E[k]), b(E[k])
            assert np.array_equal(ua, ub, equal_nan=True), f"command differs at sample {k}"
            assert_same(a, b, k)


def _ref_mrft(beta, h, rate_hz, n, bias=0.0, reading=2):
    r = ReferenceNPMRFT(beta, h, 0.0, 0.0, rate_hz, n, bias, reading)
    r.n_obs[:] = 1
    return r


def test_the_comparison_sees_a_difference():
    # a control: one relay with another a_n switches elsewhere, and the check above would say so
    rng = np.random.default_rng(9)
    n, T = 8, 300
    E = errors(rng, n, T, quant=False, stall=False, bad=False)
    a = NPMRFT(-0.7, 1.0, 0.02, 0.05, 200.0, n)
    b = ReferenceNPMRFT(-0.7, 1.0, 0.02, 0.15, 200.0, n)
    with pytest.raises(AssertionError):
        for k in range(T):
            a(E[k]), b(E[k])
            assert_same(a, b, k)
