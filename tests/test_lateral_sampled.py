"""The lateral loop over an attitude PD sampled at the control rate: frequency response, MRFT, cycle.

References are independent of the lifted model: ``uavsim.lumped.reference.LateralDiscrete``
(the exact plant stepped at a fine physics step, the session format's PD at the control
rate) driven by a sampled sinusoid or by the session format's relay (``uavsim.control.relay``).
"""

from __future__ import annotations

import numpy as np
import pytest

from uavsim.control.relay import MRFT
from uavsim.errors import UserError
from uavsim.lumped.frequency import freq_response_batch, mrft_prediction_batch
from uavsim.lumped.lateral import (
    attitude_closed_loop_batch,
    attitude_closed_loop_sampled,
    lateral_response_sampled,
    sampled_relay_cycle,
)
from uavsim.lumped.reference import LateralDiscrete
from uavsim.lumped.sampled import lift, loop_matrices, open_loop, sampled_ise

RATE = 200.0
# a fast attitude class (the box's fastest corner) under its ISE-optimal PD at 200 Hz, and a slow one
FAST = {"T_prop": 0.0158, "T1": 0.3686, "tau_in": 0.0006, "att_kp": 432.08, "att_kd": 22.669, "att_N": 314.159}
SLOW = {"T_prop": 0.2781, "T1": 1.7031, "tau_in": 0.0233, "att_kp": 26.630, "att_kd": 15.493, "att_N": 41.82}


def hold(w, rate=RATE):
    x = np.asarray(w) / (2 * rate)
    return np.sinc(x / np.pi) * np.exp(-1j * x)


def test_sampled_attitude_loop_tends_to_continuous_and_differs_at_200hz():
    w = np.geomspace(0.5, 100.0, 25)
    Tc = attitude_closed_loop_batch(w, **FAST)[0]
    err = [np.abs(attitude_closed_loop_sampled(w, **FAST, rate_hz=r)[0] / Tc - 1).max() for r in (1e4, 1e5)]
    assert err[1] < 2e-3 and err[0] / err[1] == pytest.approx(10.0, rel=0.05)  # first order in Ts
    # at 200 Hz, near the closed attitude loop's resonance (where the lateral MRFT runs): tens of percent
    Ts = attitude_closed_loop_batch(w, **FAST, rate_hz=RATE)[0]
    assert np.abs(Ts / Tc - 1).max() > 0.3
    with pytest.raises(UserError, match="one attitude PD rate"):
        attitude_closed_loop_sampled(w, **FAST, rate_hz=[200.0, 100.0])


@pytest.mark.parametrize("att", [FAST, SLOW])
def test_exact_sampled_response_is_the_held_continuous_one(att):
    """The lifted loop's response over the samples is the hold times ``freq_response_batch`` with
    ``att_rate_hz`` (aliases below 1e-6 at lateral frequencies)."""
    w = np.array([0.7, 3.0, 12.0, 40.0, 90.0])
    p = {**att, "K": 1.7, "T2": 0.8, "tau": 0.0337}
    H = lateral_response_sampled(w, RATE, **p)[0]
    G = freq_response_batch("lateral", w, **p, att_rate_hz=RATE)[0]
    np.testing.assert_allclose(H, hold(w) * G, rtol=1e-6)


@pytest.mark.parametrize("att, T2, tau, w", [(FAST, 0.3, 0.012, 35.0), (SLOW, 1.2, 0.05, 4.0)])
def test_sampled_response_matches_time_simulation(att, T2, tau, w):
    """A sinusoidal attitude reference at 200 Hz through the reference simulation: the fundamental of
    ``y_k / u_k`` (least squares on cos, sin, offset and drift, whole periods) is the exact response."""
    per = int(round(RATE * 2 * np.pi / w))
    w = 2 * np.pi * RATE / per
    sim = LateralDiscrete(1.0, att["T_prop"], att["T1"], att["tau_in"], T2, tau, att["att_kp"], att["att_kd"],
                          att["att_N"] / (2 * np.pi), 1e-3, RATE)
    n = per * 24
    y = np.empty(n)
    u = np.sin(w * np.arange(n) / RATE)
    y[0] = sim.reset()[0]
    for k in range(n - 1):
        y[k + 1] = sim.step(u[k:k + 1])[0]
    t = np.arange(n - 8 * per, n) / RATE
    D = np.column_stack([np.ones_like(t), t, np.cos(w * t), np.sin(w * t)])
    cy = np.linalg.lstsq(D, y[-8 * per:], rcond=None)[0]
    cu = np.linalg.lstsq(D, u[-8 * per:], rcond=None)[0]
    meas = (cy[2] - 1j * cy[3]) / (cu[2] - 1j * cu[3])
    H = lateral_response_sampled(np.array([w]), RATE, K=1.0, T2=T2, tau=tau, **att)[0, 0]
    assert abs(meas / H - 1) < 1e-4


def test_fit_with_the_sampled_attitude_loop_recovers_gain_and_delay():
    """What identification's lateral fit does with the sampled closed attitude loop: from the exact
    measured response (hold removed), K and the outer delay come back exactly; the continuous
    attitude loop misreads them on a fast attitude class."""
    K, T2, tau = 2.3, 0.45, 0.0213
    w = mrft_prediction_batch("lateral", -0.2, 1.0, K=K, T2=T2, tau=tau, att_rate_hz=RATE, **FAST)[0]
    G = lateral_response_sampled(w, RATE, K=K, T2=T2, tau=tau, **FAST)[0] / hold(w)
    for rate, tol in ((RATE, 1e-6), (None, None)):
        T_att = attitude_closed_loop_batch(w, **FAST, rate_hz=rate)[0]
        G0 = T_att / (1j * w * (1j * w * T2 + 1))
        K_fit = np.abs(G) / np.abs(G0)
        tau_fit = (np.angle(G0) - np.angle(G)) % (2 * np.pi) / w
        if tol is not None:
            np.testing.assert_allclose(K_fit, K, rtol=tol)
            np.testing.assert_allclose(tau_fit, tau, atol=1e-7)
        else:
            assert np.abs(tau_fit - tau).max() > 0.002  # 3 ms of 21 ms


def test_sampled_mrft_balance_and_relay_cycle():
    """The DF frequency puts the sampled response (hold included) at the MRFT phase; the exact cycle of
    the lifted loop is the reference simulation's under the session format's relay."""
    beta, T2, tau = -0.3, 0.35, 0.01
    w, a = mrft_prediction_batch("lateral", beta, 1.0, K=1.0, T2=T2, tau=tau, att_rate_hz=RATE, **FAST)
    H = lateral_response_sampled(w, RATE, K=1.0, T2=T2, tau=tau, **FAST)[0, 0]
    assert np.angle(H) == pytest.approx(-np.pi + np.arcsin(beta) + 2 * np.pi, abs=2e-3)
    assert a[0] == pytest.approx(4 * abs(H) / np.pi, rel=1e-6)
    T2s, taus = np.array([T2, 1.5]), np.array([tau, 0.06])
    period, amp = sampled_relay_cycle(beta, RATE, T2=T2s, tau=taus, **FAST)
    # the reference over the same run: each loop's last 8 cycles within its own 40 DF periods
    w = mrft_prediction_batch("lateral", beta, 1.0, K=1.0, T2=T2s, tau=taus, att_rate_hz=RATE, **FAST)[0]
    ends = np.ceil(40 * 2 * np.pi / w * RATE).astype(int)
    n = ends.max()
    sim = LateralDiscrete(1.0, FAST["T_prop"], FAST["T1"], FAST["tau_in"], T2s, taus, FAST["att_kp"], FAST["att_kd"],
                          FAST["att_N"] / (2 * np.pi), 1e-3, RATE)
    relay = MRFT(beta, 1.0, RATE, 2)
    y, u = np.empty((2, n)), np.empty((2, n))
    yk = sim.reset()
    for k in range(n):
        y[:, k], u[:, k] = yk, relay(-yk)
        yk = sim.step(u[:, k])
    for i in range(2):
        rises = np.flatnonzero((u[i, 1:ends[i]] > 0) & (u[i, :ends[i] - 1] < 0)) + 1
        r = rises[-9:]
        assert (r[-1] - r[0]) / (8 * RATE) == pytest.approx(period[i], rel=1e-12)
        assert 0.5 * np.ptp(y[i, r[0]:r[-1]]) == pytest.approx(amp[i], rel=1e-6)


def test_open_loop_closed_by_the_pd_is_the_lifted_loop():
    """``open_loop`` with the outer PD's row added back is ``loop_matrices``; the ISE is unchanged by
    evaluating a batch of mixed delays together or one loop at a time (state sizes grouped)."""
    proc = lift("lateral", RATE, K=1.0, T2=np.array([0.5, 2.0, 0.9]), tau=np.array([0.0005, 0.12, 0.031]), **SLOW)
    kp, kd, N = np.array([0.4, 0.2, 0.3]), np.array([0.2, 0.3, 0.15]), np.array([30.0, 12.0, 20.0])
    A, b, c = open_loop(proc)
    M, _, _ = loop_matrices(proc, kp, kd, N)
    D = M - A  # the PD's output row entering along the input column: rank one
    iE = proc.nx + proc.d_in.max() + 1
    D[:, iE + 1] = 0.0  # the outer PD's derivative state (its filter differs; no input in the open loop)
    rows = np.arange(3)
    j = np.argmax(np.abs(b), axis=1)
    r = D[rows, j] / b[rows, j][:, None]
    np.testing.assert_allclose(D, np.einsum("bi,bj->bij", b, r), atol=1e-9)
    a = N / RATE / (1 + N / RATE)
    np.testing.assert_allclose(r[rows, np.argmax(c, axis=1)], -(kp + kd * a * RATE), rtol=1e-12)
    q_all = sampled_ise(proc, kp, kd, N)
    q_one = np.array([sampled_ise(proc.take([i]), kp[i], kd[i], N[i])[0] for i in range(3)])
    np.testing.assert_allclose(q_all, q_one, rtol=1e-12)
