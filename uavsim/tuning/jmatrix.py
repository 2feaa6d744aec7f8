"""Relative sensitivity J between classes (paper eq. 24, as a ratio).

    J_ij = Q(C_i, G_j) / Q(C_j, G_j)        rows i: predicted class, columns j: true class

``Q`` is the unit-step ISE (``uavsim.lumped.ise``, exact delays, Parseval).
Every process is gain-normalized at its own MRFT phase (``|G_j(j Omega_j)| = 1``,
which the MRFT amplitude measures), so the rule's controller of class i is the
normalized ``C_i(s) = c1 (1 + Td_i s / (1 + s / N_i))``, ``Td_i = c3 2 pi / Omega_i``,
``N_i = 10 Omega_i``: in this convention a controller depends on its class only
through ``Omega_i``. J is clipped to ``[1, 1e3]``; an unstable loop gives 1e3.
The symmetrized ``J_(ij) = max(J_ij, J_ji)`` is used for spacing.

Vectorized: for each true process j, its frequency response is computed once
on a log grid around ``Omega_j`` and all candidate controllers are evaluated at
once, so an n x n matrix costs n passes over an (n, W) array.

    from uavsim.tuning.jmatrix import j_matrix
    J = j_matrix("altitude", omega, c1, c3, T_prop=..., T1=..., tau=...)   # (n, n)
"""

from __future__ import annotations

import numpy as np

from uavsim.lumped.frequency import freq_response_batch
from uavsim.lumped.ise import frequency_grid, loop_is_stable_batch
from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO

__all__ = ["J_MAX", "ise_normalized", "j_matrix", "deterioration", "symmetrize"]

J_MAX = 1e3


def _pick(params: dict, j) -> dict:
    return {k: (np.asarray(v).reshape(-1)[j] if np.size(v) > 1 else v) for k, v in params.items() if v is not None}


def ise_normalized(
    family: str,
    proc_omega: np.ndarray,
    ctrl_omega: np.ndarray,
    c1: float,
    c3: float,
    n: int = 2000,
    span: float = 1e3,
    include_own: bool = False,
    **params,
):
    """ISE of every gain-normalized process under every normalized rule controller.

    Parameters
    ----------
    family : str
        Loop family.
    proc_omega : ndarray (P,)
        DF MRFT frequency of each process, rad/s.
    ctrl_omega : ndarray (M,)
        MRFT frequency of each controller's class, rad/s.
    c1, c3 : float
        Rule constants.
    n, span : int, float
        Frequency grid: n log points over ``[Omega_j/span, Omega_j*span]``.
    **params
        Process parameters, arrays (P,) or scalars (K ignored: normalized).

    Returns
    -------
    Q : ndarray (M, P)
        ISE (output^2 s for the normalized process); inf where unstable.
    q_own : ndarray (P,), only with ``include_own``
        ISE of each process under its own rule controller.
    """
    proc_omega = np.asarray(proc_omega, float).reshape(-1)
    ctrl_omega = np.asarray(ctrl_omega, float).reshape(-1)
    P, M = len(proc_omega), len(ctrl_omega)
    params = {k: v for k, v in params.items() if k != "K"}
    Td = c3 * 2 * np.pi / ctrl_omega
    Nf = DERIVATIVE_FILTER_RATIO * ctrl_omega
    Q = np.empty((M, P))
    q_own = np.empty(P)
    for j in range(P):
        if include_own:
            Td_j = np.append(Td, c3 * 2 * np.pi / proc_omega[j])
            Nf_j = np.append(Nf, DERIVATIVE_FILTER_RATIO * proc_omega[j])
        else:
            Td_j, Nf_j = Td, Nf
        w = frequency_grid(np.array([proc_omega[j]]), n, span)  # (1, W)
        sub = _pick(params, j)
        Gw = freq_response_batch(family, np.concatenate([w, [[proc_omega[j]]]], axis=1), K=1.0, **sub)[0]
        G = Gw[:-1] / np.abs(Gw[-1])  # normalized: |G(j Omega_j)| = 1
        s = 1j * w[0]
        C = c1 * (1.0 + Td_j[:, None] * s[None, :] / (1.0 + s[None, :] / Nf_j[:, None]))  # (M[+1], W)
        L = C * G[None, :]
        S2 = 1.0 / np.abs(1.0 + L) ** 2
        lw = np.log(w[0])
        f = S2 / w[0][None, :]
        mid = (0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(lw)[None, :]).sum(axis=1)
        # low end: L ~ Kn c1 / (j w) with the normalized gain Kn = 1/|G1(j Omega_j)|
        Kk = c1 / np.abs(Gw[-1])
        low = np.arctan(w[0, 0] / Kk) / Kk
        q = (mid + low + 1.0 / w[0, -1]) / np.pi
        q = np.where(loop_is_stable_batch(L), q, np.inf)
        Q[:, j] = q[:M]
        if include_own:
            q_own[j] = q[M]
    return (Q, q_own) if include_own else Q


def _clipJ(Q: np.ndarray, q_own: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        J = Q / q_own[None, :]
    J = np.where(np.isfinite(J), J, J_MAX)
    return np.clip(J, 1.0, J_MAX)


def j_matrix(family: str, omega: np.ndarray, c1: float, c3: float, n: int = 2000, **params) -> np.ndarray:
    """J matrix of a set of classes, shape (n_classes, n_classes), rows predicted, columns true.

    ``omega`` (n_classes,) are the classes' DF MRFT frequencies (rad/s); ``params``
    their process parameters (arrays (n_classes,)).
    """
    Q = ise_normalized(family, omega, omega, c1, c3, n=n, **params)
    J = _clipJ(Q, np.diag(Q).copy())
    np.fill_diagonal(J, 1.0)
    return J


def deterioration(
    family: str, point_omega: np.ndarray, class_omega: np.ndarray, c1: float, c3: float, n: int = 2000, **point_params
) -> np.ndarray:
    """J of each point process under each class controller, shape (n_classes, n_points).

    ``Q(C_i, G_x) / Q(C_x, G_x)`` with ``C_x`` the rule controller of the point itself.
    """
    Q, own = ise_normalized(family, point_omega, class_omega, c1, c3, n=n, include_own=True, **point_params)
    return _clipJ(Q, own)


def symmetrize(J: np.ndarray) -> np.ndarray:
    """``J_(ij) = max(J_ij, J_ji)``."""
    return np.maximum(J, J.T)
