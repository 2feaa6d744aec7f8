"""Boiko's baselines: hand-computed instants, equivalence with MRFT, errors."""

import numpy as np
import pytest

from uavsim.control.baselines import InhibitedMRFT, TwoRelayMRFT
from uavsim.control.relay import MRFT
from uavsim.errors import UserError
from uavsim.lumped.reference import LumpedDiscrete
from uavsim.noise.analysis import cycle_stats


def run(relay, e):
    out, sw = [], []
    for ek in e:
        out.append(relay(np.atleast_1d(ek)).copy())
        sw.append(relay.switched.copy())
    return np.array(out), np.array(sw)


def test_inhibit_zero_equals_mrft_on_random_signals():
    rng = np.random.default_rng(3)
    e = np.cumsum(rng.standard_normal((400, 5)), axis=0) * 0.1 + 0.3 * rng.standard_normal((400, 5))
    u1, _ = run(InhibitedMRFT(-0.6, 1.0, 0.0, 100.0, 5, bias=0.1), e)
    u2, _ = run(MRFT(-0.6, 1.0, 100.0, 5, bias=0.1, reading=1), e)  # its tracking is the version-1 one
    np.testing.assert_array_equal(u1, u2)


def test_inhibition_blocks_switch_back():
    # plain MRFT switches at k=5 and back at k=7 (see test_relay); with 3 samples of
    # inhibition (0.3 s at 10 Hz) the switch back at 7 is blocked; at k=8 (8-5 = 3 samples)
    # the min 0.2 was set at k=8 itself (not confirmed) -> no switch; the sequence then rises:
    # k=9 (0.5): min 0.2 confirmed, 0.5 >= b1 = 0.1 -> switch at 9
    e = np.array([0.1, 0.5, 1.0, 0.8, 0.6, 0.4, 0.3, 0.35, 0.2, 0.5])
    _, sw = run(InhibitedMRFT(-0.5, 1.0, 0.3, 10.0, 1), e)
    assert np.flatnonzero(sw[:, 0]).tolist() == [5, 9]


def test_two_relay_hand_values():
    # beta = -0.6: h0 = 0.8 h, h1 = 0.6 h
    r = TwoRelayMRFT(beta=-0.6, h=1.0, rate_hz=100.0, n=1)
    e = [0.5, 0.7, 0.7, 0.4, -0.1, -0.3, -0.2]
    u, sw = run(r, e)
    # k0: sign(e)=+1, slope relay starts like it: 1.4; k1: rising 1.4; k2: flat keeps +: 1.4;
    # k3: falling 0.8-0.6 = 0.2; k4: e<0, falling: -1.4; k5: -1.4; k6: rising: -0.8+0.6 = -0.2
    np.testing.assert_allclose(u[:, 0], [1.4, 1.4, 1.4, 0.2, -1.4, -1.4, -0.2])
    assert sw[:, 0].tolist() == [False, False, False, True, True, False, True]
    assert r.h0[0] ** 2 + r.h1[0] ** 2 == pytest.approx(1.0)


def test_two_relay_matches_mrft_cycle_noise_free():
    # same describing function as MRFT: the periods agree closely on a lumped process
    rate = 200.0
    res = {}
    for name, relay in (("mrft", MRFT(-0.73, 1.0, rate, 1)), ("two", TwoRelayMRFT(-0.73, 1.0, rate, 1)),
                        ("inh", InhibitedMRFT(-0.73, 1.0, 0.05, rate, 1))):
        sim = LumpedDiscrete.inner(2.0, 0.08, 0.6, 0.02, 1 / rate, 1)
        y = sim.reset()
        ys, us = [], []
        for _ in range(int(8 * rate)):
            u = relay(-y)
            ys.append(y[0])
            us.append(u[0])
            y = sim.step(u)
        t = np.arange(len(ys)) / rate
        res[name] = cycle_stats(t, np.array(ys), np.array(us))
    assert res["mrft"].n_cycles >= 5
    assert res["two"].period == pytest.approx(res["mrft"].period, rel=0.1)
    assert res["inh"].period == pytest.approx(res["mrft"].period, rel=0.03)


@pytest.mark.parametrize("kw, word", [({"beta": 1.0}, "beta"), ({"h": 0.0}, "h must"),
                                      ({"t_inhibit": -0.1}, "inhibition")])
def test_bad_parameters(kw, word):
    args = {"beta": -0.7, "h": 1.0, "t_inhibit": 0.1}
    args.update(kw)
    with pytest.raises(UserError, match=word):
        InhibitedMRFT(rate_hz=200.0, n=1, **args)
    if "t_inhibit" not in kw:
        args.pop("t_inhibit")
        with pytest.raises(UserError, match=word):
            TwoRelayMRFT(rate_hz=200.0, n=1, **args)
