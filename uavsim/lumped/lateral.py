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

import numpy as np

__all__ = ["attitude_filter", "attitude_closed_loop_batch", "DERIVATIVE_FILTER_RATIO"]

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


def attitude_closed_loop_batch(omega: np.ndarray, T_prop, T1, tau_in, att_kp, att_kd, att_N=None) -> np.ndarray:
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

    Returns
    -------
    ndarray, complex, shape (B, W)
    """
    from uavsim.lumped.frequency import _col, freq_response_batch

    if att_N is None:
        att_N = attitude_filter(T_prop, T1, tau_in)
    omega = np.asarray(omega, dtype=float)
    B = max(omega.shape[0] if omega.ndim == 2 else 1, *(np.size(v) for v in (T_prop, T1, tau_in, att_kp, att_kd, att_N)))
    w = np.broadcast_to(omega if omega.ndim == 2 else omega[None, :], (B, omega.shape[-1]))
    s = 1j * w
    C = _col(att_kp, B) + _col(att_kd, B) * s / (1.0 + s / _col(att_N, B))
    L = C * freq_response_batch("attitude", w, 1.0, T_prop, T1, tau_in)
    return L / (1.0 + L)
