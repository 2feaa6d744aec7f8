"""Frequency response of the lumped loops and the describing-function MRFT prediction.

Every lumped model has an exact frequency response (delays enter as
``exp(-j w tau)``, no Pade approximation):

    inner:    G(jw) = K e^{-j w tau} / (jw (T_prop jw + 1)(T1 jw + 1))
    lateral:  G(jw) = K e^{-j w tau_out} T_att(jw) / (jw (T2 jw + 1))

(``T_att``: :func:`attitude_closed_loop_batch`, the model in ``uavsim.lumped.lateral``). The MRFT with parameter ``beta`` and
relay amplitude ``h`` has the describing function
``N(a) = 4h/(pi a) (sqrt(1 - beta^2) - j beta)``; harmonic balance
``N(a0) G(j Omega0) = -1`` gives

    arg G(j Omega0) = -pi + asin(beta)        a0 = 4 h |G(j Omega0)| / pi

(``beta < 0``: the relay leads, the test runs where the process lags by more
than 180 deg). ``mrft_prediction`` solves it; the exact (non-sinusoidal) cycle
is in ``uavsim.lumped.simulate.exact_limit_cycle``.

    from uavsim.lumped import LumpedParams, freq_response, mrft_prediction
    p = LumpedParams("altitude", K=1.0, T_prop=0.3, T1=0.2, tau=0.0128)
    G = freq_response(p, np.array([1.0, 10.0]))
    omega, amp = mrft_prediction(p, beta=-0.73, h=1.0)
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams

__all__ = [
    "freq_response",
    "freq_response_batch",
    "unwrapped_phase_batch",
    "mrft_prediction",
    "mrft_prediction_batch",
    "check_beta",
    "batch_args",
    "column",
    "attitude_filter",
    "attitude_closed_loop_batch",
    "DEFAULT_BETA",
    "DERIVATIVE_FILTER_RATIO",
]

#: MRFT parameter of the flight tests (paper: altitude beta_z0 = -0.72/-0.73); the tuning
#: rule's default (``uavsim.tuning.rule``), and the beta at which the attitude filter is set
DEFAULT_BETA = -0.73


def check_beta(beta: float) -> float:
    """Raise ``UserError`` unless ``-1 < beta < 1``; return it as float."""
    if not isinstance(beta, (int, float, np.floating)) or not math.isfinite(beta) or not -1.0 < beta < 1.0:
        raise UserError(f"MRFT beta must be in (-1, 1), got {beta!r}")
    return float(beta)


def column(x, n: int) -> np.ndarray:
    """Broadcast a scalar or (B,) array to shape (B, 1)."""
    a = np.asarray(x, dtype=float)
    return np.broadcast_to(a.reshape(-1) if a.ndim else a, (n,)).reshape(n, 1)


def freq_response_batch(
    family: str,
    omega: np.ndarray,
    K,
    T_prop,
    T1,
    tau,
    T2=None,
    tau_in=None,
    att_kp=None,
    att_kd=None,
    att_N=None,
    att_rate_hz=None,
) -> np.ndarray:
    """Frequency response of many lumped processes of one family.

    Parameters
    ----------
    family : str
        ``"attitude"``, ``"altitude"`` (both inner) or ``"lateral"``.
    omega : ndarray
        Frequencies, rad/s, shape (W,) (same for all processes) or (B, W).
    K, T_prop, T1, tau : float or ndarray (B,)
        Gain, time constants (s) and delay (s; the outer delay for lateral).
    T2, tau_in, att_kp, att_kd, att_N : float or ndarray (B,), lateral only
        Drag time constant (s), attitude delay (s), attitude PD gains for the
        unit-gain attitude process, and its derivative filter (rad/s). ``att_N``
        defaults to ``10 * Omega_att`` (see ``uavsim.lumped.lateral``).
    att_rate_hz : float or None, lateral only
        Rate of the attitude PD, Hz: the attitude loop is closed by the PD sampled there
        (``uavsim.lumped.lateral.attitude_closed_loop_sampled``: the response over the
        controller's samples with the command's hold removed). None: the continuous PD.

    Returns
    -------
    ndarray, complex, shape (B, W)
    """
    omega = np.asarray(omega, dtype=float)
    sizes = [np.size(v) for v in (K, T_prop, T1, tau, T2, tau_in, att_kp, att_kd, att_N) if v is not None]
    B = max([omega.shape[0] if omega.ndim == 2 else 1, *sizes])
    w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
    s = 1j * w
    if family in ("attitude", "altitude", "roll", "pitch"):
        Tp, T1c, tc = column(T_prop, B), column(T1, B), column(tau, B)
        return column(K, B) * np.exp(-s * tc) / (s * (Tp * s + 1.0) * (T1c * s + 1.0))
    if family in ("lateral", "lateral_x", "lateral_y"):
        if T2 is None or tau_in is None or att_kp is None or att_kd is None:
            raise UserError("lateral frequency response needs T2, tau_in, att_kp and att_kd")
        # the attitude loop on the shared frequencies when they are (an attitude class under many lateral
        # processes): (1, W) broadcast against the batch
        Tatt = attitude_closed_loop_batch(omega if omega.ndim == 1 else w, T_prop, T1, tau_in, att_kp, att_kd, att_N,
                                          rate_hz=att_rate_hz)
        return column(K, B) * np.exp(-s * column(tau, B)) * Tatt / (s * (column(T2, B) * s + 1.0))
    raise UserError(f"unknown loop family {family!r}")


def batch_args(p: LumpedParams) -> dict:
    """The keyword arguments of the ``*_batch`` functions for one process (its parameters, B = 1)."""
    d = {"K": p.K, "T_prop": p.T_prop, "T1": p.T1, "tau": p.tau}
    if p.family == "lateral":
        d.update(T2=p.T2, tau_in=p.tau_in, att_kp=p.att_kp, att_kd=p.att_kd, att_N=2 * math.pi * p.att_filter_hz)
    return d


def freq_response(p: LumpedParams, omega: np.ndarray) -> np.ndarray:
    """Exact frequency response of one process.

    Parameters
    ----------
    p : LumpedParams
        The process (checked).
    omega : ndarray, shape (W,)
        Frequencies, rad/s.

    Returns
    -------
    ndarray, complex, shape (W,)
    """
    p.check()
    return freq_response_batch(p.family, np.atleast_1d(omega), **batch_args(p))[0]


def unwrapped_phase_batch(family: str, omega: np.ndarray, **params) -> np.ndarray:
    """Continuous phase (rad) of G(j w), shape (B, W), starting near -pi/2 at low w.

    Inner loops use the closed form ``-pi/2 - atan(w T_prop) - atan(w T1) - w tau``
    (sign of K ignored); lateral loops unwrap the numerical phase of ``T_att`` along
    ``omega`` (which must be increasing and fine enough, e.g. 2000 log points).
    """
    omega = np.asarray(omega, dtype=float)
    if family in ("attitude", "altitude", "roll", "pitch"):
        B = max(np.size(params[k]) for k in ("T_prop", "T1", "tau"))
        w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
        return (
            -np.pi / 2
            - np.arctan(w * column(params["T_prop"], B))
            - np.arctan(w * column(params["T1"], B))
            - w * column(params["tau"], B)
        )
    G = freq_response_batch(family, omega, **{**params, "K": 1.0})
    ph = np.unwrap(np.angle(G), axis=-1)
    # anchor the low-frequency end at -pi/2 (integrator; T_att(0) = 1)
    return ph - 2 * np.pi * np.round((ph[:, :1] + np.pi / 2) / (2 * np.pi))


def mrft_prediction_batch(
    family: str, beta: float, h: float = 1.0, w_lo: float = 1e-2, w_hi: float = 1e6, **params
) -> tuple[np.ndarray, np.ndarray]:
    """Harmonic-balance (DF) MRFT frequency and amplitude for many processes.

    Parameters
    ----------
    family : str
        Loop family.
    beta : float
        MRFT parameter in (-1, 1).
    h : float
        Relay amplitude (command units).
    w_lo, w_hi : float
        Search band, rad/s.
    **params
        As ``freq_response_batch`` (arrays of shape (B,) or scalars). A lateral process with
        ``att_rate_hz`` is a sampled loop: the relay's command is held at that rate (the
        attitude PD reads it only at its samples), so the balance is on ``hold(w) G(j w)``,
        ``hold(w) = sinc(w Ts / 2) e^{-j w Ts / 2}``, and the amplitude is of the sampled output.

    Returns
    -------
    omega : ndarray (B,)
        Oscillation frequency, rad/s (the lowest crossing of the target phase);
        NaN where the phase never reaches it in the band.
    amplitude : ndarray (B,)
        Predicted amplitude of the error (output) oscillation, ``4 h |G| / pi``.
    """
    beta = check_beta(beta)
    target = -np.pi + math.asin(beta)
    if family in ("attitude", "altitude", "roll", "pitch"):
        # the phase -pi/2 - atan(w T_prop) - atan(w T1) - w tau decreases monotonically:
        # bisection in log w, then Newton to machine precision (no grid, any batch size)
        B = max(np.size(params[k]) for k in ("T_prop", "T1", "tau"))
        Tp, T1, tau = (np.broadcast_to(np.asarray(params[k], float).reshape(-1), (B,)) for k in ("T_prop", "T1", "tau"))

        def phase(w):
            return -np.pi / 2 - np.arctan(w * Tp) - np.arctan(w * T1) - w * tau

        a = np.full(B, math.log(w_lo))
        b = np.full(B, math.log(w_hi))
        has = phase(np.exp(b)) <= target
        for _ in range(60):
            m = 0.5 * (a + b)
            lower = phase(np.exp(m)) > target
            a = np.where(lower, m, a)
            b = np.where(lower, b, m)
        w = np.exp(0.5 * (a + b))
        for _ in range(3):
            df = -Tp / (1 + (w * Tp) ** 2) - T1 / (1 + (w * T1) ** 2) - tau
            w = w - (phase(w) - target) / df
        omega = w
    else:
        rate = one_rate(params.get("att_rate_hz"))
        if rate is not None:
            # the attitude PD samples its reference, so the relay acts at the samples too: the
            # balance is on the sequence response, the command's hold included (below Nyquist)
            w_hi = min(w_hi, 0.999 * math.pi * rate)
        wg = np.geomspace(w_lo, w_hi, 4000)
        ph = unwrapped_phase_batch(family, wg, **params) - _hold_lag(wg, rate)
        B = ph.shape[0]
        below = ph <= target
        has = below.any(axis=1)
        i1 = np.clip(np.argmax(below, axis=1), 1, len(wg) - 1)
        rows = np.arange(B)
        # refine inside the bracket on a local grid of 64 points (vectorized), then interpolate
        lw0, lw1 = np.log(wg[i1 - 1]), np.log(wg[i1])
        u = np.linspace(0.0, 1.0, 64)
        lw = lw0[:, None] + (lw1 - lw0)[:, None] * u[None, :]
        G = freq_response_batch(family, np.exp(lw), **{**params, "K": 1.0}) * _hold(np.exp(lw), rate)
        # continue the unwrapped phase from the bracket's left end
        ph_loc = np.unwrap(np.angle(G), axis=1)
        ph_loc = ph_loc - ph_loc[:, :1] + ph[rows, i1 - 1][:, None]
        j1 = np.clip(np.argmax(ph_loc <= target, axis=1), 1, 63)
        p0, p1 = ph_loc[rows, j1 - 1], ph_loc[rows, j1]
        x0, x1 = lw[rows, j1 - 1], lw[rows, j1]
        omega = np.exp(x0 + (target - p0) / (p1 - p0) * (x1 - x0))
    omega[~has] = np.nan
    G = np.full(B, np.nan, dtype=complex)
    ok = np.isfinite(omega)
    if ok.any():
        sel = {k: (np.asarray(v).reshape(-1)[ok] if np.size(v) > 1 else v) for k, v in params.items()}
        G[ok] = freq_response_batch(family, omega[ok][:, None], **sel)[:, 0]
        if family not in ("attitude", "altitude", "roll", "pitch"):
            G[ok] *= _hold(omega[ok], params.get("att_rate_hz"))
    return omega, 4.0 * h * np.abs(G) / np.pi


def one_rate(rate_hz) -> float | None:
    """A sampled loop's rate, Hz, from a scalar or a batch's array of one value (None stays None)."""
    if rate_hz is None:
        return None
    r = np.unique(np.asarray(rate_hz, dtype=float).reshape(-1))
    if r.size != 1 or not (math.isfinite(r[0]) and r[0] > 0):
        raise UserError(f"a batch of lateral processes needs one attitude PD rate > 0 Hz, got {r.tolist()}")
    return float(r[0])


def _hold(omega, rate_hz) -> np.ndarray | float:
    """Fundamental of a command held over ``1/rate_hz`` against its samples (1 without a rate)."""
    if rate_hz is None:
        return 1.0
    x = np.asarray(omega, dtype=float) / (2.0 * one_rate(rate_hz))
    return np.sinc(x / np.pi) * np.exp(-1j * x)


def _hold_lag(omega, rate_hz) -> np.ndarray | float:
    """The hold's phase lag ``omega / (2 rate_hz)``, rad (0 without a rate)."""
    return 0.0 if rate_hz is None else np.asarray(omega, dtype=float) / (2.0 * one_rate(rate_hz))


def mrft_prediction(p: LumpedParams, beta: float, h: float = 1.0) -> tuple[float, float]:
    """Harmonic-balance prediction of the MRFT oscillation of one process.

    Parameters
    ----------
    p : LumpedParams
        The process.
    beta : float
        MRFT parameter, -1 < beta < 1.
    h : float
        Relay amplitude, > 0.

    Returns
    -------
    omega : float
        Oscillation frequency, rad/s.
    amplitude : float
        Amplitude of the output oscillation, output units (``4 h |G(j omega)| / pi``).
    """
    p.check()
    if not h > 0:
        raise UserError(f"relay amplitude h must be > 0, got {h!r}")
    w, a = mrft_prediction_batch(p.family, beta, h, **batch_args(p))
    if not np.isfinite(w[0]):
        raise UserError(f"{p.loop}: no MRFT oscillation predicted for beta={beta} (phase never reaches the target)")
    return float(w[0]), float(a[0])


#: the rule's derivative filter: N = DERIVATIVE_FILTER_RATIO * Omega (rad/s)
DERIVATIVE_FILTER_RATIO = 10.0


def attitude_filter(T_prop, T1, tau_in, beta: float | None = None) -> np.ndarray:
    """Derivative filter (rad/s) of the attitude PD: ``10 * Omega_att``, shape (B,)."""
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
    if att_N is None:
        att_N = attitude_filter(T_prop, T1, tau_in)
    if rate_hz is not None:
        return attitude_closed_loop_sampled(omega, T_prop, T1, tau_in, att_kp, att_kd, att_N, rate_hz)
    omega = np.asarray(omega, dtype=float)
    B = max(omega.shape[0] if omega.ndim == 2 else 1, *(np.size(v) for v in (T_prop, T1, tau_in, att_kp, att_kd, att_N)))
    w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
    s = 1j * w
    C = column(att_kp, B) + column(att_kd, B) * s / (1.0 + s / column(att_N, B))
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
    over its own samples (``uavsim.data.preprocess.held_response`` of ``G``) is

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
    a = Ts * column(att_N, B) / (1.0 + Ts * column(att_N, B))
    Cd = column(att_kp, B) + column(att_kd, B) * a * (1.0 - zi) / (Ts * (1.0 - (1.0 - a) * zi))
    Ga = freq_response_batch("attitude", w, 1.0, Tp, T1c, tin)
    return Ga * Cd / (1.0 + Cd * Gd)
