"""Lateral lumped model: the outer loop seen through the closed attitude loop.

The lateral command ``u`` is a pitch (or roll) reference. The attitude loop
``G_a(s) = e^{-tau_in s} / (s (T_prop s + 1)(T1 s + 1))`` (unit gain) is closed
by the PD of its attitude class,
``C(s) = att_kp + att_kd s / (1 + s / att_N)``, so that

    T_att(s) = C G_a / (1 + C G_a)
    G_lat(s) = K e^{-tau_out s} T_att(s) / (s (T2 s + 1))

The attitude derivative filter follows the tuning rule, ``att_N = 10 Omega_att``
with ``Omega_att`` the DF MRFT frequency of the attitude process at the
attitude rule's ``beta`` (``uavsim.tuning.rule.DEFAULT_BETA``), unless given.

    from uavsim.lumped.lateral import attitude_closed_loop_batch
    T = attitude_closed_loop_batch(np.geomspace(0.1, 100, 50), 0.05, 0.5, 0.01, 2.0, 0.3)
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import check_beta

__all__ = ["attitude_filter", "attitude_closed_loop_batch", "attitude_closed_loop_sampled", "lateral_response_sampled",
           "sampled_relay_cycle", "DERIVATIVE_FILTER_RATIO"]

#: the rule's derivative filter: N = DERIVATIVE_FILTER_RATIO * Omega (rad/s)
DERIVATIVE_FILTER_RATIO = 10.0


def attitude_filter(T_prop, T1, tau_in, beta: float | None = None) -> np.ndarray:
    """Derivative filter (rad/s) of the attitude PD: ``10 * Omega_att``, shape (B,)."""
    from uavsim.lumped.frequency import mrft_prediction_batch
    from uavsim.tuning.rule import DEFAULT_BETA

    w, _ = mrft_prediction_batch(
        "attitude", DEFAULT_BETA if beta is None else beta, 1.0, K=1.0, T_prop=T_prop, T1=T1, tau=tau_in
    )
    return DERIVATIVE_FILTER_RATIO * w


def attitude_closed_loop_batch(omega: np.ndarray, T_prop, T1, tau_in, att_kp, att_kd, att_N=None,
                               rate_hz: float | None = None) -> np.ndarray:
    """Complementary sensitivity ``T_att(j w)`` of the closed attitude loop.

    Parameters
    ----------
    omega : ndarray, shape (W,) or (B, W)
        Frequencies, rad/s.
    T_prop, T1, tau_in : float or ndarray (B,)
        Attitude process (unit gain), s.
    att_kp, att_kd : float or ndarray (B,)
        Attitude PD gains for the unit-gain process.
    att_N : float or ndarray (B,) or None
        Derivative filter, rad/s; None -> ``attitude_filter(T_prop, T1, tau_in)``.
    rate_hz : float or None
        The PD's rate, Hz: ``attitude_closed_loop_sampled`` (the PD sampled with a zero-order
        hold, as flown); None: the continuous PD.

    Returns
    -------
    ndarray, complex, shape (B, W)
    """
    from uavsim.lumped.frequency import _col, freq_response_batch

    if att_N is None:
        att_N = attitude_filter(T_prop, T1, tau_in)
    if rate_hz is not None:
        return attitude_closed_loop_sampled(omega, T_prop, T1, tau_in, att_kp, att_kd, att_N, rate_hz)
    omega = np.asarray(omega, dtype=float)
    B = max(omega.shape[0] if omega.ndim == 2 else 1, *(np.size(v) for v in (T_prop, T1, tau_in, att_kp, att_kd, att_N)))
    w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
    s = 1j * w
    C = _col(att_kp, B) + _col(att_kd, B) * s / (1.0 + s / _col(att_N, B))
    L = C * freq_response_batch("attitude", w, 1.0, T_prop, T1, tau_in)
    return L / (1.0 + L)


def _zoh_delayed(A: np.ndarray, b: np.ndarray, Ts: float, tau) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH discretization of B plants (A (B, n, n), b (B, n)) with input delays ``tau`` (B,).

    ``x_{k+1} = Phi x_k + G_old v_{k-d-1} + G_new v_{k-d}`` with ``tau = (d + f) Ts``: over one
    period the delayed command is the older sample for ``f Ts``, then the newer one.
    Returns ``(Phi, G_old, G_new, d)``.
    """
    from scipy.linalg import expm

    from uavsim.lumped.sampled import delay_split

    Bn, n, _ = A.shape
    d, f = delay_split(tau, Ts)

    def aug(h: np.ndarray) -> np.ndarray:
        M = np.zeros((Bn, n + 1, n + 1))
        M[:, :n, :n] = A
        M[:, :n, n] = b
        return expm(M * h[:, None, None])

    E_new = aug((1.0 - f) * Ts)  # e^{A (1-f) Ts} and its input integral
    E_old = aug(f * Ts)
    E = aug(np.full(Bn, Ts))
    G_old = np.einsum("bij,bj->bi", E_new[:, :n, :n], E_old[:, :n, n])
    return E[:, :n, :n], G_old, E_new[:, :n, n], d


def attitude_closed_loop_sampled(omega: np.ndarray, T_prop, T1, tau_in, att_kp, att_kd, att_N,
                                 rate_hz: float) -> np.ndarray:
    """``T_att`` of the attitude loop closed by its PD sampled at ``rate_hz`` (zero-order hold).

    The PD reads the attitude error at the samples ``t_k = k Ts`` (``uavsim.control.pd``:
    ``C_d(z) = kp + kd a (1 - 1/z) / (Ts (1 - (1 - a)/z))``, ``a = Ts N / (1 + Ts N)``) and its
    held command drives the continuous attitude process ``G_a`` (unit gain, delay ``tau_in``),
    whose exact ZOH discretization is ``G_d(z)``. For a reference sequence ``u_k = e^{j w k Ts}``
    the command sequence is ``C_d / (1 + C_d G_d) u_k`` at ``z = e^{j w Ts}``, and the
    attitude's component at ``w`` is that times the hold's ``(1 - e^{-j w Ts}) / (j w Ts)``
    and ``G_a(j w)``. This function returns

        T_att(w) = G_a(j w) C_d(z) / (1 + C_d(z) G_d(z))

    without the hold factor, so that the lateral response a controller at ``rate_hz`` measures
    over its own samples (``uavsim.learning.identify.held_response`` of ``G``) is

        hold(w) K e^{-j w tau_out} T_att(w) / (j w (T2 j w + 1))

    up to the aliases of the harmonics at ``w + m 2 pi / Ts`` (below 1e-5 of the fundamental
    for lateral cycles; ``lateral_response_sampled`` is the exact sampled response). As
    ``rate_hz -> inf`` it tends to the continuous ``attitude_closed_loop_batch``.

    Parameters
    ----------
    omega : ndarray (W,) or (B, W)
        Frequencies, rad/s (> 0, below the Nyquist frequency ``pi rate_hz``).
    T_prop, T1, tau_in, att_kp, att_kd, att_N : float or ndarray (B,)
        Attitude process (unit gain, s), its PD and derivative filter (rad/s).
    rate_hz : float
        The attitude PD's rate, Hz.

    Returns
    -------
    ndarray, complex, shape (B, W)
    """
    from uavsim.lumped.frequency import _col, freq_response_batch, one_rate

    Ts = 1.0 / one_rate(rate_hz)
    omega = np.asarray(omega, dtype=float)
    B = max(omega.shape[0] if omega.ndim == 2 else 1, *(np.size(v) for v in (T_prop, T1, tau_in, att_kp, att_kd, att_N)))
    w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
    Tp, T1c, tin = (np.broadcast_to(np.asarray(v, float).reshape(-1), (B,)) for v in (T_prop, T1, tau_in))
    A = np.zeros((B, 3, 3))
    A[:, 0, 1] = 1.0
    A[:, 1, 1] = -1.0 / T1c
    A[:, 1, 2] = 1.0 / T1c
    A[:, 2, 2] = -1.0 / Tp
    b = np.zeros((B, 3))
    b[:, 2] = 1.0 / Tp
    Phi, G_old, G_new, d = _zoh_delayed(A, b, Ts, tin)
    zi = np.exp(-1j * w * Ts)  # 1/z
    z = 1.0 / zi
    # theta = first entry of (z I - Phi)^{-1} g: Phi is upper triangular (so is A), back substitution
    P = Phi[:, :, :, None]
    g = (G_old[:, :, None] * zi[:, None, :] + G_new[:, :, None]) * (zi ** d[:, None])[:, None, :]
    x2 = g[:, 2] / (z - P[:, 2, 2])
    x1 = (g[:, 1] + P[:, 1, 2] * x2) / (z - P[:, 1, 1])
    Gd = (g[:, 0] + P[:, 0, 1] * x1 + P[:, 0, 2] * x2) / (z - P[:, 0, 0])
    a = Ts * _col(att_N, B) / (1.0 + Ts * _col(att_N, B))
    Cd = _col(att_kp, B) + _col(att_kd, B) * a * (1.0 - zi) / (Ts * (1.0 - (1.0 - a) * zi))
    Ga = freq_response_batch("attitude", w, 1.0, Tp, T1c, tin)
    return Ga * Cd / (1.0 + Cd * Gd)


def _lifted_open_loop(rate_hz: float, params: dict):
    """``(A, b, c)`` of the lifted lateral loops without the outer controller, and the index of the
    attitude PD's previous-error state."""
    from uavsim.lumped.sampled import _layout, lift, open_loop

    proc = lift("lateral", rate_hz, **{"K": 1.0, **params})
    return (*open_loop(proc), _layout(proc)["iEa"])


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
