"""The relay's bias trim (``bias_trim = "duty"``) on the exact lumped loops.

A relay bias ``b`` (a hover-command error) makes an integrating loop's relay
cycle asymmetric; the trimmed relay moves its bias from each cycle's duty, so
that its cycle becomes the bias-free one to the duty's resolution. Checked
against the exact lumped cycle of plain MRFT without bias
(``simulate_relay_batch``, an independent implementation) and against relays of a
sample of duty's bias; the relay's states are read back from the trimmed command.
"""

from __future__ import annotations

import numpy as np
import pytest

from uavsim.control.relay import (
    MRFT,
    NPMRFT,
    TRIM_AFTER_SWITCHES,
    TRIM_STEP_MAX,
    relay_sign,
    untrimmed,
)
from uavsim.errors import UserError
from uavsim.lumped.reference import LumpedDiscrete
from uavsim.lumped.simulate import simulate_relay_batch
from uavsim.noise.analysis import cycle_stats

RATE = 200.0
BETA = -0.73
#: (K, T_prop, T1, tau): the altitude and attitude boxes' corners and middle (slowest cycles ~1.5 s)
PROCESSES = np.array([[1.0, 0.1, 0.5, 0.03], [2.0, 0.3, 2.0, 0.06], [8.0, 0.015, 0.2, 0.002],
                      [1.0, 0.05, 1.0, 0.01], [0.5, 0.2, 0.3, 0.04], [12.0, 0.03, 1.0, 0.002]])
BIASES = np.array([0.5, -0.5, 0.3, -0.2, 0.45, -0.4])


def run(relay, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Close ``relay`` on the exact loops of PROCESSES: e, u and the relay's states (n, T)."""
    p = PROCESSES
    sim = LumpedDiscrete.inner(p[:, 0], p[:, 1], p[:, 2], p[:, 3], 1.0 / RATE)
    y = sim.reset()
    T = int(seconds * RATE)
    E, U, S = np.empty((3, len(p), T))
    for k in range(T):
        E[:, k] = -y
        U[:, k] = relay(-y)
        S[:, k] = relay.sign
        y = sim.step(U[:, k])
    return E, U, S


def cycle_errors(E: np.ndarray, S: np.ndarray, ref: dict) -> np.ndarray:
    """(n, 2): each run's steady period (samples) and amplitude (fraction) error against the exact bias-free cycle."""
    t = np.arange(E.shape[1]) / RATE
    out = []
    for i in range(E.shape[0]):
        exact = cycle_stats(ref["t"], ref["e"][i], ref["u"][i])
        c = cycle_stats(t, E[i], S[i])
        out.append(((c.period - exact.period) * RATE, c.amplitude / exact.amplitude - 1))
    return np.array(out)


def test_trimmed_cycle_is_the_bias_free_cycle_to_a_sample_of_duty():
    # a quarter of the duty error per cycle: the slowest cycle here (2 s) needs ~20 cycles from 0.5 h
    T = int(60.0 * RATE)
    p, n = PROCESSES, len(PROCESSES)
    ref = simulate_relay_batch("inner", BETA, 1.0, 1.0 / RATE, T, K=p[:, 0], T_prop=p[:, 1], T1=p[:, 2], tau=p[:, 3])
    N = np.array([cycle_stats(ref["t"], ref["e"][i], ref["u"][i]).period for i in range(n)]) * RATE
    relay = MRFT(BETA, 1.0, RATE, n, bias=BIASES, bias_trim="duty")
    E, _, S = run(relay, T / RATE)
    trimmed = cycle_errors(E, S, ref)
    # the bias left is within the cycle's duty resolution (a sample of either half-wave), not the one drawn
    assert np.all(np.abs(relay.bias) <= 2.0 / N), relay.bias
    # A sampled relay's cycle is the exact bias-free one only at zero bias: a bias of a sample of
    # duty already moves a cycle of 24-80 samples by samples and its amplitude by up to ~15 %.
    # The trimmed cycle is as close to the bias-free one as such a relay's (constant biases of
    # one and two samples of duty, either sign), within a sample and 1 %.
    small = np.array([cycle_errors(*run(MRFT(BETA, 1.0, RATE, n, bias=b), T / RATE)[::2], ref)
                      for b in (1 / N, -1 / N, 2 / N, -2 / N)])
    worst = np.abs(small).max(axis=0)
    assert np.all(np.abs(trimmed[:, 0]) <= worst[:, 0] + 1), (trimmed, worst)
    assert np.all(np.abs(trimmed[:, 1]) <= worst[:, 1] + 0.01), (trimmed, worst)
    # control: at the drawn bias (0.2-0.5 h) the cycles are several times further off
    drawn = cycle_errors(*run(MRFT(BETA, 1.0, RATE, n, bias=BIASES), T / RATE)[::2], ref)
    assert np.abs(drawn[:, 1]).mean() > 3 * np.abs(trimmed[:, 1]).mean(), (drawn, trimmed)


def test_states_read_back_from_the_trimmed_command():
    relay = NPMRFT(BETA, 1.0, 0.02, 0.001, RATE, len(PROCESSES), bias=BIASES, bias_trim="duty")
    _, U, S = run(relay, 12.0)
    assert not np.allclose(U, S + BIASES[:, None])  # the bias moved
    np.testing.assert_array_equal(relay_sign(U, 1.0, BIASES), S)
    np.testing.assert_array_equal(untrimmed(U, 1.0, BIASES), S + BIASES[:, None])
    for i in range(len(PROCESSES)):  # one run at a time, as a session's
        np.testing.assert_array_equal(relay_sign(U[i], 1.0, BIASES[i]), S[i])
    # the command moves only at switches, the bias by at most TRIM_STEP_MAX h at a switch up
    du = np.diff(U, axis=1)
    dS = np.diff(S, axis=1)
    assert np.all(du[dS == 0] == 0)
    assert np.all(np.abs(du[dS > 0] - 2) <= TRIM_STEP_MAX + 1e-12)
    assert np.all(du[dS < 0] == -2)


def test_no_trim_before_the_start_up_switches_and_off_keeps_the_bias():
    relay = MRFT(BETA, 1.0, RATE, len(PROCESSES), bias=BIASES, bias_trim="duty")
    moved_at = []
    p = PROCESSES
    sim = LumpedDiscrete.inner(p[:, 0], p[:, 1], p[:, 2], p[:, 3], 1.0 / RATE)
    y = sim.reset()
    for _ in range(int(5.0 * RATE)):
        u = relay(-y)
        moved = relay.bias != BIASES
        moved_at.append(np.where(moved, relay.n_sw, -1))
        y = sim.step(u)
    first = np.array([m[m >= 0].min() if (m >= 0).any() else 99 for m in np.array(moved_at).T])
    assert np.all(first >= TRIM_AFTER_SWITCHES)
    _, U, _ = run(MRFT(BETA, 1.0, RATE, len(p), bias=BIASES), 5.0)
    np.testing.assert_allclose(np.abs(U - BIASES[:, None]), 1.0)


def test_unknown_trim_is_refused():
    with pytest.raises(UserError, match="bias_trim"):
        NPMRFT(BETA, 1.0, 0.02, 0.0, RATE, 1, bias_trim="integral")
