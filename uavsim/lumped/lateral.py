"""Lateral lumped model: the outer loop seen through the closed attitude loop.

The lateral command ``u`` is a pitch (or roll) reference. The attitude loop
``G_a(s) = e^{-tau_in s} / (s (T_prop s + 1)(T1 s + 1))`` (unit gain) is closed
by the PD of its attitude class,
``C(s) = att_kp + att_kd s / (1 + s / att_N)``, so that

    T_att(s) = C G_a / (1 + C G_a)
    G_lat(s) = K e^{-tau_out s} T_att(s) / (s (T2 s + 1))

The attitude derivative filter follows the tuning rule, ``att_N = 10 Omega_att``
with ``Omega_att`` the DF MRFT frequency of the attitude process at the
attitude rule's ``beta`` (``uavsim.lumped.frequency.DEFAULT_BETA``), unless given.

    from uavsim.lumped.lateral import attitude_closed_loop_batch
    T = attitude_closed_loop_batch(np.geomspace(0.1, 100, 50), 0.05, 0.5, 0.01, 2.0, 0.3)
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import (
    DERIVATIVE_FILTER_RATIO,
    attitude_closed_loop_batch,
    attitude_closed_loop_sampled,
    attitude_filter,
    check_beta,
)

__all__ = ["attitude_filter", "attitude_closed_loop_batch", "attitude_closed_loop_sampled", "lateral_response_sampled",
           "sampled_relay_cycle", "DERIVATIVE_FILTER_RATIO"]


def _lifted_open_loop(rate_hz: float, params: dict):
    """``(A, b, c)`` of the lifted lateral loops without the outer controller, and the index of the
    attitude PD's previous-error state."""
    from uavsim.lumped.sampled import lift, lifted_layout, open_loop

    proc = lift("lateral", rate_hz, **{"K": 1.0, **params})
    return (*open_loop(proc), lifted_layout(proc)["iEa"])


def lateral_response_sampled(omega: np.ndarray, rate_hz: float, **params) -> np.ndarray:
    """Exact response of the sampled lateral loop over the controller's samples, (B, W) complex.

    The ratio of the fundamentals of ``y_k = x(t_k - tau)`` and of the outer command sequence
    ``u_k`` at ``omega`` (rad/s, below ``pi rate_hz``), both PDs' sampling, holds and delays
    included, from the lifted loop (``uavsim.lumped.sampled.open_loop``): ``c (z I - A)^{-1} b``
    at ``z = e^{j w Ts}``. It is what a controller at ``rate_hz`` measures; with the hold
    removed it is ``freq_response_batch("lateral", ..., att_rate_hz=rate_hz)`` up to aliases.

    Parameters
    ----------
    omega : ndarray (W,)
    rate_hz : float
    **params
        As ``uavsim.lumped.sampled.lift`` for the lateral family (``K`` default 1; ``att_N`` rad/s).
    """
    A, b, c, _ = _lifted_open_loop(rate_hz, params)
    z = np.exp(1j * np.asarray(omega, dtype=float) / float(rate_hz))
    n = A.shape[1]
    Mz = z[None, :, None, None] * np.eye(n)[None, None] - A[:, None]
    x = np.linalg.solve(Mz, np.broadcast_to(b[:, None, :, None], Mz.shape[:3] + (1,)).astype(complex))[..., 0]
    return np.einsum("bwn,bn->bw", x, c)


def sampled_relay_cycle(beta: float, rate_hz: float, *, h: float = 1.0, n_periods: int = 40, n_measure: int = 8,
                        spread: bool = False, **params):
    """The MRFT cycle of B lateral loops with the relay and both PDs sampled at ``rate_hz``.

    The relay (``uavsim.control.relay.MRFT``, the session format's semantics, on the error
    ``e_k = -y_k``) runs on the exact lifted loop (``uavsim.lumped.sampled.open_loop``: exact at
    the samples, no time step), from rest, the attitude PD started at the first sample as
    ``uavsim.control.pd.PD``. A continuous relay gives the same cycle up to its continuous
    extremum: the attitude PD reads its reference only at the samples. Each loop is measured
    over its last ``n_measure`` whole cycles (rising edges of the relay output) within its own
    ``n_periods`` DF periods.

    A sampled relay need not settle into one periodic cycle: switching on whole samples, it
    can lock to patterns of cycles of different lengths and amplitudes (near the closed
    attitude loop's resonance, lateral cycles of 40-60 samples vary by several percent from
    one to the next). The figures are then averages; ``spread`` returns how much the measured
    cycles differ.

    Parameters
    ----------
    beta : float
        MRFT parameter.
    rate_hz : float
        Rate of the relay and both PDs, Hz.
    h : float
        Relay amplitude.
    n_periods, n_measure : int
        Simulated length in DF periods of each loop, and whole cycles measured at its end.
    spread : bool
        Also return the spreads.
    **params
        As ``uavsim.lumped.sampled.lift`` for the lateral family (``K`` default 1).

    Returns
    -------
    period : ndarray (B,)
        Mean period over the measured cycles, s (NaN where fewer cycles than asked).
    amplitude : ndarray (B,)
        Half the peak-to-peak of the sampled output over the measured cycles.
    period_spread, amplitude_spread : ndarray (B,), only with ``spread``
        ``(max - min) / mean`` of the measured cycles' periods and of their half peak-to-peak.
    """
    from uavsim.control.relay import MRFT
    from uavsim.lumped.frequency import mrft_prediction_batch

    beta = check_beta(beta)
    p = {"K": 1.0, **params}
    w, _ = mrft_prediction_batch("lateral", beta, h, **{**p, "att_rate_hz": rate_hz})
    if not np.all(np.isfinite(w)):
        raise UserError(f"lateral: no MRFT oscillation at beta={beta} for some loops")
    A, b, c, i_att = _lifted_open_loop(rate_hz, p)
    B = A.shape[0]
    steps = int(math.ceil(n_periods * 2.0 * math.pi / w.min() * rate_hz))
    relay = MRFT(beta, h, rate_hz, B)
    z = np.zeros((B, A.shape[1]))
    y = np.zeros((B, steps))
    u = np.zeros((B, steps))
    At = np.swapaxes(A, 1, 2)
    for k in range(steps):
        y[:, k] = np.einsum("bn,bn->b", c, z)
        u[:, k] = relay(-y[:, k])
        if k == 0:
            # the attitude PD starts at the first sample (its first raw difference is 0,
            # ``uavsim.control.pd``): its previous error is its first, u_0 - theta_0 = u_0
            z[:, i_att] = u[:, 0]
        z = np.einsum("bn,bnm->bm", z, At) + b * u[:, k:k + 1]
    period, amplitude, p_spread, a_spread = (np.full(B, np.nan) for _ in range(4))
    # each loop measured at the end of its own n_periods (a result independent of the batch)
    ends = np.ceil(n_periods * 2.0 * np.pi / w * rate_hz).astype(np.int64)
    for i in range(B):
        rises = np.flatnonzero((u[i, 1:ends[i]] > 0) & (u[i, :ends[i] - 1] < 0)) + 1
        if len(rises) >= n_measure + 1:
            r = rises[-(n_measure + 1):]
            period[i] = (r[-1] - r[0]) / (n_measure * rate_hz)
            seg = y[i, r[0]:r[-1]]
            amplitude[i] = 0.5 * (seg.max() - seg.min())
            d = np.diff(r)
            a = np.array([np.ptp(y[i, r[k]:r[k + 1]]) for k in range(n_measure)])
            p_spread[i] = np.ptp(d) / d.mean()
            a_spread[i] = np.ptp(a) / a.mean()
    return (period, amplitude, p_spread, a_spread) if spread else (period, amplitude)
