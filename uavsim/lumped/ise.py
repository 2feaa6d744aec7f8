"""Step-response ISE of a PD loop, computed in the frequency domain (exact delays).

For a unit reference step the error is ``E(s) = S(s) / s`` with
``S = 1 / (1 + C G)``. By Parseval the infinite-horizon ISE is

    Q = (1/pi) * integral_0^inf |S(jw)|^2 / w^2 dw

which needs no time simulation and no Pade approximation, and vectorizes over
thousands of (controller, process) pairs: this is what makes a full J matrix
cheap. The integral runs on a log grid around a reference frequency with the
two ends closed analytically (below ``w_min``: ``L ~ K kp / (j w)`` so
``|E|^2 ~ 1 / (w^2 + (K kp)^2)``; above ``w_max``: ``|E|^2 ~ 1/w^2``).
Closed-loop stability is decided by the Nyquist criterion on the same grid
(the open loop is stable apart from the integrator): the unwrapped phase of
``1 + L(j w)`` must rise by the no-encirclement amount; otherwise Q = inf.

The controller is ``C(s) = kp + kd s / (1 + s/N)``.

    from uavsim.lumped.ise import step_ise_batch
    Q = step_ise_batch("altitude", kp=[1.0], kd=[0.3], N=[80.0], omega_ref=[8.0],
                       K=1.0, T_prop=0.1, T1=0.5, tau=0.02)
"""

from __future__ import annotations

import numpy as np

from uavsim.lumped.frequency import column, freq_response_batch

__all__ = ["step_ise_batch", "loop_is_stable_batch", "frequency_grid"]


def frequency_grid(omega_ref: np.ndarray, n: int, span: float) -> np.ndarray:
    """Log grid (B, n) from omega_ref/span to omega_ref*span."""
    u = np.linspace(-np.log(span), np.log(span), n)
    return np.asarray(omega_ref, float).reshape(-1, 1) * np.exp(u)[None, :]


def _loop(family: str, w: np.ndarray, kp, kd, N, params: dict) -> np.ndarray:
    B = w.shape[0]
    s = 1j * w
    C = column(kp, B) + column(kd, B) * s / (1.0 + s / column(N, B))
    return C * freq_response_batch(family, w, **params)


def loop_is_stable_batch(L: np.ndarray) -> np.ndarray:
    """Nyquist test on ``L(j w)`` sampled on an increasing grid, shape (B, W) -> bool (B,).

    With an open loop stable apart from one integrator, the closed loop is stable
    iff ``arg(1 + L)`` changes, from the low end to the high end, by the
    principal-value difference (no net 2 pi turn): each pair of right-half-plane
    closed-loop poles subtracts 2 pi.
    """
    F = 1.0 + L
    ang = np.angle(F)
    d = np.diff(ang, axis=1)
    d = (d + np.pi) % (2 * np.pi) - np.pi
    total = d.sum(axis=1)
    principal = ang[:, -1] - ang[:, 0]
    principal = (principal + np.pi) % (2 * np.pi) - np.pi
    return np.abs(total - principal) < np.pi


def step_ise_batch(
    family: str,
    kp,
    kd,
    N,
    omega_ref,
    n: int = 3000,
    span: float = 1e3,
    return_stable: bool = False,
    **params,
):
    """Infinite-horizon ISE of a unit step, for B (controller, process) pairs.

    Parameters
    ----------
    family : str
        ``attitude``, ``altitude`` or ``lateral``.
    kp, kd, N : float or ndarray (B,)
        PD gains and derivative filter (rad/s).
    omega_ref : float or ndarray (B,)
        Reference frequency (rad/s) the grid is centred on, e.g. the MRFT frequency.
    n : int
        Grid points (over ``2 log10(span)`` decades).
    span : float
        Grid runs from ``omega_ref/span`` to ``omega_ref*span``.
    return_stable : bool
        Also return the stability flags.
    **params
        Process parameters as ``freq_response_batch`` (K must be > 0).

    Returns
    -------
    Q : ndarray (B,)
        ISE, output-units^2 s; ``inf`` where the closed loop is unstable.
    stable : ndarray of bool (B,), only with ``return_stable``
    """
    sizes = [np.size(v) for v in (kp, kd, N, omega_ref, *params.values()) if v is not None]
    B = max(sizes)
    w = frequency_grid(np.broadcast_to(np.asarray(omega_ref, float), (B,)), n, span)
    L = _loop(family, w, kp, kd, N, params)
    S = 1.0 / (1.0 + L)
    lw = np.log(w)
    f = np.abs(S) ** 2 / w  # |S|^2/w^2 dw = |S|^2/w dlnw
    mid = 0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(lw, axis=1)
    Kk = np.broadcast_to(np.asarray(params["K"], float) * np.asarray(kp, float), (B,))
    low = np.arctan(w[:, 0] / Kk) / Kk
    high = 1.0 / w[:, -1]
    Q = (mid.sum(axis=1) + low + high) / np.pi
    stable = loop_is_stable_batch(L) & (Kk > 0)
    Q = np.where(stable, Q, np.inf)
    return (Q, stable) if return_stable else Q
