"""Switch instants of NPMRFT / MRFT against hand computation (docs/formats/session.md semantics).

Signals are sampled sinusoids ``sin(2 pi k / 40)`` (40 samples per cycle, true
maximum at k = 10, minimum at k = 30) with hand-placed noise samples. The
expected instants are worked out in the comments from the normative rules:
running extremum of the half-wave (reading 2: from the crossing of the cycle's
centre, midway between the last tracked maximum and minimum, initially 0;
reading 1: since the last switch), confirmed once ``k - k_ext >= n_obs``,
switch down when ``e <= -(beta e_max + a_n (1 - beta))``, up when
``e >= -beta e_min + a_n (1 - beta)``.
"""

import math

import numpy as np
import pytest

from uavsim.control.relay import MRFT, NPMRFT, beta_min, check_relay_params
from uavsim.errors import UserError

RATE = 40.0  # Hz: Ts = 25 ms, so tau_obs = 0.075 s is exactly 3 samples


def sine(n=44):
    return np.sin(2 * np.pi * np.arange(n) / 40)


def switches(relay, e):
    """Run the relay over e (T,) for one episode; return (sample indices of switches, outputs)."""
    ks, us = [], []
    for k, ek in enumerate(e):
        us.append(float(relay(np.array([ek]))[0]))
        if relay.switched[0]:
            ks.append(k)
    return ks, np.array(us)


def test_noise_free_sine_switch_instants():
    # e_max = 1 at k=10, confirmed at k=13; -b2 = 0.7: sin(135 deg) = 0.7071 > 0.7 at k=15,
    # sin(144 deg) = 0.588 at k=16 -> switch down at 16. Then e_min = -1 at k=30,
    # confirmed k=33; b1 = -0.7: k=35 gives -0.7071 < -0.7, k=36 gives -0.588 -> switch up at 36.
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1)
    ks, u = switches(r, sine())
    assert ks == [16, 36]
    assert u[0] == 1.0 and u[16] == -1.0 and u[36] == 1.0


def test_local_peak_before_max_false_switches_mrft_not_npmrft():
    e = sine()
    e[7] += 0.1   # 0.991: a local peak before the true maximum (k=10)
    e[8] -= 0.3   # 0.651 <= 0.7 * 0.991 = 0.694: a noise dip right after it
    # plain MRFT: max 0.991 set at k=7 is confirmed at k=8, and 0.651 <= 0.694 -> false switch at 8
    ks, _ = switches(MRFT(beta=-0.7, h=1.0, rate_hz=RATE, n=1), e)
    assert ks[0] == 8
    # NP-MRFT, tau_obs = 3 samples: at k=8, 9 the peak of k=7 is not confirmed; k=10 sets
    # the true maximum, confirmed at 13; the true switch at 16 as without noise
    ks, _ = switches(NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1), e)
    assert ks[0] == 16


def test_local_peak_after_max_is_tracked_then_confirmed():
    e = sine()
    e[12] += 0.06  # 0.951 + 0.06 = 1.011 > 1: a noise peak after the true maximum becomes e_max
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1)
    ks, _ = switches(r, e)
    # confirmed at k=15 (12 + 3); -b2 = 0.7 * 1.011 = 0.7077 >= sin(135 deg) = 0.7071 -> switch at 15,
    # one sample early: the inflated peak raised the switching level
    assert ks[0] == 15
    e2 = sine()
    e2[12] += 0.04  # 0.991 < 1: a lower local peak after the maximum changes nothing
    ks, _ = switches(NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1), e2)
    assert ks[0] == 16


def test_a_n_correction_lowers_both_switching_levels():
    # a_n = 0.1: -b2 = 0.7 - 0.1 * 1.7 = 0.53 -> k=16 (0.588) no, k=17 (0.454) yes;
    # b1 = -0.7 + 0.17 = -0.53 -> k=36 (-0.588) no, k=37 (-0.454) yes
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.1, rate_hz=RATE, n=1)
    ks, _ = switches(r, sine())
    assert ks == [17, 37]
    # the same correction with the inflated peak of the previous test: 0.7077 - 0.17 = 0.5377 -> k=17
    e = sine()
    e[12] += 0.06
    ks, _ = switches(NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.1, rate_hz=RATE, n=1), e)
    assert ks[0] == 17


def test_tau_obs_confirmation_delays_the_switch():
    # beta = 0.5: switch down when e <= -0.5 e_max; with a large tau_obs = 12 samples
    # (0.3 s) the max at k=10 is confirmed only at k=22 (e = -0.309, above -0.5);
    # k=23: -0.454, k=24: -0.588 <= -0.5 -> switch at 24 (same as MRFT, whose confirmed
    # max waits for the level only). With tau_obs = 16 samples: confirmed at 26 -> switch at 26.
    ks, _ = switches(MRFT(beta=0.5, h=1.0, rate_hz=RATE, n=1), sine())
    assert ks[0] == 24
    ks, _ = switches(NPMRFT(beta=0.5, h=1.0, tau_obs=0.3, a_n=0.0, rate_hz=RATE, n=1), sine())
    assert ks[0] == 24
    ks, _ = switches(NPMRFT(beta=0.5, h=1.0, tau_obs=0.4, a_n=0.0, rate_hz=RATE, n=1), sine())
    assert ks[0] == 26


def test_tau_obs_rounding_to_samples():
    r = NPMRFT(beta=-0.73, h=1.0, tau_obs=6.5 / 200, a_n=0.0, rate_hz=200.0, n=2)
    assert r.n_obs.tolist() == [7, 7]
    r = NPMRFT(beta=-0.73, h=1.0, tau_obs=0.015, a_n=0.0, rate_hz=200.0, n=1)
    assert r.n_obs.tolist() == [3]  # 0.015 * 200 = 3.0000000000000004 must not become 4


def test_first_sample_rule_and_bias():
    r = NPMRFT(beta=-0.7, h=2.0, tau_obs=0.05, a_n=0.0, rate_hz=RATE, n=3, bias=0.5)
    u = r(np.array([0.0, -1e-9, 0.3]))
    assert u.tolist() == [2.5, -1.5, 2.5]  # e >= 0 -> +h, else -h; bias added
    m = MRFT(beta=-0.7, h=1.0, rate_hz=RATE, n=1, bias=-0.25)
    assert m(np.array([-0.2]))[0] == -1.25


def test_mrft_confirms_one_sample_after_extremum_and_restarts_tracker():
    # hand case of the version-1 restart rule: the tracker restarts at the switch sample (0.4, k=5),
    # so an uptick right after a switch down is a "confirmed minimum" of 0.3 for plain MRFT
    e = [0.1, 0.5, 1.0, 0.8, 0.6, 0.4, 0.3, 0.35, 0.2]
    ks, _ = switches(MRFT(beta=-0.5, h=1.0, rate_hz=10.0, n=1, reading=1), np.array(e))
    # k=2 max 1.0 (confirmed k=3); -b2 = 0.5: 0.8, 0.6 no; 0.4 -> switch at 5.
    # k=6 min 0.3 (confirmed k=7), b1 = 0.15: 0.35 >= 0.15 -> switch back at 7
    assert ks == [5, 7]


def uptick_after_switch():
    """The sine with a noise bump right after the switch down at k=16 (e there: 0.588)."""
    e = sine()
    e[17] = 0.55                       # a lower value: the running minimum since the switch ...
    e[18] = e[19] = e[20] = 0.6        # ... stands for 3 samples
    return e


def test_reading1_confirms_a_minimum_on_the_wrong_side_of_zero():
    # tracker restarted at (0.588, 16); min 0.55 at k=17 confirmed at k=20 (n_obs=3);
    # b1 = 0.7 * 0.55 = 0.385 and e[20] = 0.6 >= 0.385 -> false switch up at 20
    ks, _ = switches(NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1, reading=1),
                     uptick_after_switch())
    assert ks[:2] == [16, 20]


def test_reading2_tracks_the_half_wave_after_the_centre():
    # no relay bias: the half-wave of the minimum starts at the zero crossing. After the switch
    # down at 16 (0.588) k=17..20 (0.55, 0.6) are not its half-wave; k=21 (-0.156) starts it;
    # min -1 at k=30, confirmed k=33, b1 = -0.7 -> 36, exactly as without the bump
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1)
    assert r.reading == 2
    armed = []
    ks = []
    for k, ek in enumerate(uptick_after_switch()):
        r(np.array([ek]))
        armed.append(bool(r.armed[0]))
        if r.switched[0]:
            ks.append(k)
    assert ks == [16, 36]
    assert armed[16:21] == [False] * 5 and armed[21]
    assert r.centre[0] == 0.0


def test_deadlock_guard_starts_tracking_after_a_fraction_of_the_last_half_period():
    # after the switch down at 16 the error never comes back below zero: it rises from 0.6. H1 = 16 (start to first switch), H2 = 0; beta = -0.7:
    # rho = 1/4 + asin(0.7)/pi = 0.4968, W = ceil(0.4968 * 16) = 8 -> tracking starts at k=24
    # (the guard); the rising error keeps its minimum at 24, confirmed at 27 (n_obs=3),
    # b1 = 0.7 e[24] < e[27] -> switch up at 27: the relay resumes cycling
    e = sine(60)
    e[17:] = 0.6 + 0.01 * np.arange(43)
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1)
    ks, guards = [], []
    for k, ek in enumerate(e):
        r(np.array([ek]))
        if r.switched[0]:
            ks.append(k)
        if r.guard[0]:
            guards.append(k)
    assert ks[:2] == [16, 27]
    assert guards[0] == 24
    # reading 1 switches back as soon as the switch sample (0.588, a minimum since the switch)
    # is confirmed: k=19
    ks1, _ = switches(NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=1, reading=1), e)
    assert ks1[:2] == [16, 19]


def test_guard_fraction_and_tau_obs_limit():
    from uavsim.control.relay import guard_fraction, tau_obs_limit

    assert float(guard_fraction(-0.73)) == pytest.approx(0.25 + math.asin(0.73) / math.pi)
    assert float(guard_fraction(0.3)) == 0.25 and float(guard_fraction(-0.999)) < 0.75 + 1e-9
    # sinusoid: the level -beta a0 is reached acos(-beta) / 2 pi of a period after the peak
    assert float(tau_obs_limit(-0.73, 1.0)) == pytest.approx(math.acos(0.73) / (2 * math.pi))
    # the paper's beta_min is the more conservative bound
    assert float(beta_min(float(tau_obs_limit(-0.73, 1.0)), 1.0)) > -0.73


def test_retune_changes_settings_from_the_next_sample():
    r = NPMRFT(beta=-0.7, h=1.0, tau_obs=0.075, a_n=0.0, rate_hz=RATE, n=2)
    r.retune(tau_obs=[0.025, 0.1], a_n=0.1)
    assert r.n_obs.tolist() == [1, 4] and r.a_n.tolist() == [0.1, 0.1]
    with pytest.raises(UserError, match="a_n"):
        r.retune(a_n=-1.0)


def test_unknown_reading_is_refused():
    with pytest.raises(UserError, match="reading"):
        NPMRFT(beta=-0.7, h=1.0, tau_obs=0.0, a_n=0.0, rate_hz=RATE, n=1, reading=3)


def test_vectorized_rows_are_independent():
    e = sine()
    e2 = sine()
    e2[12] += 0.06
    r = NPMRFT(beta=[-0.7, -0.7], h=1.0, tau_obs=0.075, a_n=[0.0, 0.1], rate_hz=RATE, n=2)
    sw = []
    for k in range(44):
        r(np.array([e[k], e2[k]]))
        sw.append(r.switched.copy())
    sw = np.array(sw)
    assert np.flatnonzero(sw[:, 0]).tolist() == [16, 36]
    assert np.flatnonzero(sw[:, 1])[0] == 17


def test_beta_min_paper_example():
    # paper: T_n / T0 = 0.015 gives beta_min = -0.906 (with the 2 pi the printed formula lacks)
    assert round(float(beta_min(0.015, 1.0)), 3) == -0.906
    assert float(beta_min(0.015, 1.0)) == pytest.approx(-1 + math.sin(2 * math.pi * 0.015))
    assert float(beta_min(0.0, 1.0)) == -1.0


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"beta": 1.0}, "beta"),
        ({"beta": -1.0}, "beta"),
        ({"beta": float("nan")}, "beta"),
        ({"h": 0.0}, "h must be > 0"),
        ({"h": -1.0}, "h must be > 0"),
        ({"tau_obs": -0.01}, "tau_obs"),
        ({"a_n": -0.1}, "a_n"),
    ],
)
def test_bad_parameters_raise_clear_errors(kwargs, word):
    args = {"beta": -0.73, "h": 1.0, "tau_obs": 0.02, "a_n": 0.0}
    args.update(kwargs)
    with pytest.raises(UserError, match=word):
        NPMRFT(rate_hz=200.0, n=2, **args)
    with pytest.raises(UserError, match=word):
        check_relay_params(**args)


def test_bad_parameters_mrft():
    with pytest.raises(UserError, match="beta"):
        MRFT(beta=1.5, h=1.0, rate_hz=200.0, n=1)
    with pytest.raises(UserError, match="h must"):
        MRFT(beta=-0.5, h=[1.0, 0.0], rate_hz=200.0, n=2)
