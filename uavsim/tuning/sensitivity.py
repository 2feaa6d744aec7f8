"""Relative sensitivity J at the control rate, against the ISE-optimal PD.

    J(C, G) = Q(C, G) / Q(C*_G, G)

``Q`` is the exact step ISE at the control rate (``uavsim.lumped.sampled``) and
``C*_G`` the ISE-optimal PD of ``G`` at that rate (``uavsim.tuning.optimal``), so
``J >= 1`` with equality only for the optimum, whatever controller is judged.

A class's table gains are for the unit-gain class (K = 1). Identification
scales them by the process gain it estimates from the measured first-harmonic
response ``|G(j w)|`` at the oscillation frequency ``w``. Two estimates
(``scaling``):

* ``"mrft"`` (default): the measured magnitude against the class's own at its
  MRFT point, ``K_hat = |G(j w)| / |G_i(j Omega_i)|_{K=1}`` -- the authors'
  ``a / a_class`` recovery in describing-function terms. The class's gains then
  keep their loop gain at the MRFT point, the normalization the grid's J
  spacing was designed in (processes gain-normalized at their MRFT phase);
* ``"response"``: the class's lags fitted at the measured frequency,
  ``K_hat = |G(j w)| / |G_i(j w)|_{K=1}`` (``uavsim.ident.response.fit_response``).

Gains applied: ``kp_i / K_hat``, ``kd_i / K_hat``. Here ``w`` is the true
process's DF MRFT frequency at the grid's beta. Between a class and itself both
give ``K_hat = K``, so ``J_ii = 1``. ``J_ij`` (rows: the class answered,
columns: the true class) is this cost of class ``i``'s table gains on class
``j``. An unstable pair counts ``J_MAX`` (as the grids' J).

The ISE-optimal gains are less forgiving than the rule's: at 200 Hz with
``"response"`` scaling 8 of 94 (attitude) and 7 of 413 (altitude) neighbour
pairs across ``Omega`` levels are unstable one way (the optimum of a class with
less delay on its slower neighbour); with ``"mrft"`` scaling 1 and 0.

    from uavsim.tuning.sensitivity import estimated_gain, table_j_matrix
    J = table_j_matrix("altitude", 200.0, class_params, kp, kd, N, ise_opt, omega)   # (n, n)
    K_hat = estimated_gain("altitude", w_meas, true_params, class_params, class_omega)
"""

from __future__ import annotations

import numpy as np

from uavsim.lumped.frequency import freq_response_batch
from uavsim.lumped.params import loop_family
from uavsim.lumped.sampled import lift, sampled_ise
from uavsim.tuning.jmatrix import J_MAX

__all__ = ["SCALINGS", "estimated_gain", "controller_ise", "table_j_matrix", "j_of_points"]

#: how identification estimates the process gain the table's gains are divided by
SCALINGS = ("mrft", "response")

#: pairs evaluated per batched ISE call (memory: a few hundred MB at the lateral state size)
_CHUNK = 2048


def _take(params: dict[str, np.ndarray], idx: np.ndarray) -> dict[str, np.ndarray]:
    return {k: (np.asarray(v, dtype=np.float64).reshape(-1)[idx] if np.size(v) > 1 else np.full(len(idx), float(v)))
            for k, v in params.items() if v is not None}


def estimated_gain(family: str, omega, true_params: dict, class_params: dict, class_omega=None,
                   scaling: str = "mrft") -> np.ndarray:
    """The process gain identification estimates, ``K_hat``, (B,) (module docstring).

    Parameters
    ----------
    family : str
    omega : ndarray (B,)
        The true processes' MRFT frequencies, rad/s (where the response is measured).
    true_params, class_params : dict
        Process parameters (as ``freq_response_batch``, arrays (B,) or scalars); the class's
        ``K`` is ignored (taken as 1).
    class_omega : ndarray (B,) or None
        The classes' own MRFT frequencies, rad/s (``scaling="mrft"``).
    scaling : str
        ``"mrft"`` or ``"response"``.
    """
    from uavsim.errors import UserError

    fam = loop_family(family)
    if scaling not in SCALINGS:
        raise UserError(f"unknown gain scaling {scaling!r} (expected one of {', '.join(SCALINGS)})")
    w = np.asarray(omega, dtype=np.float64).reshape(-1, 1)
    Gt = freq_response_batch(fam, w, **true_params)[:, 0]
    if scaling == "mrft":
        if class_omega is None:
            raise UserError("the mrft gain scaling needs the classes' own MRFT frequencies")
        w = np.asarray(class_omega, dtype=np.float64).reshape(-1, 1)
    Gc = freq_response_batch(fam, w, **{**class_params, "K": 1.0})[:, 0]
    return np.abs(Gt) / np.abs(Gc)


def controller_ise(family: str, rate_hz: float, proc_params: dict, kp, kd, N, kick: bool = False) -> np.ndarray:
    """Exact ISE of B (process, PD) pairs, chunked (``uavsim.lumped.sampled``), (B,)."""
    fam = loop_family(family)
    kp, kd, N = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (kp, kd, N))
    B = max(kp.size, *(np.size(v) for v in proc_params.values() if v is not None))
    kp, kd, N = (np.broadcast_to(v, (B,)) for v in (kp, kd, N))
    out = np.empty(B)
    for s in range(0, B, _CHUNK):
        idx = np.arange(s, min(B, s + _CHUNK))
        proc = lift(fam, rate_hz, **_take(proc_params, idx))
        with np.errstate(over="ignore", invalid="ignore"):
            out[idx] = sampled_ise(proc, kp[idx], kd[idx], N[idx], kick=kick)
    return out


def _clip_j(Q: np.ndarray, q_opt: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        J = Q / q_opt
    J = np.where(np.isfinite(J), J, J_MAX)
    return np.clip(J, 1.0, J_MAX)


def j_of_points(family: str, rate_hz: float, point_params: dict, point_omega, point_ise, class_params: dict,
                class_omega, kp, kd, N, pairs: tuple[np.ndarray, np.ndarray] | None = None, kick: bool = False,
                scaling: str = "mrft") -> np.ndarray:
    """J of class controllers on processes, identification's gain scaling included.

    Parameters
    ----------
    family : str
        Loop family.
    rate_hz : float
        Control rate, Hz.
    point_params : dict
        P true processes (arrays (P,) or scalars, with ``K``).
    point_omega : ndarray (P,)
        Their DF MRFT frequencies at the grid's beta, rad/s (where the gain is estimated).
    point_ise : ndarray (P,)
        Their optimal ISE at ``rate_hz``.
    class_params : dict
        C unit-gain classes (arrays (C,) or scalars).
    class_omega : ndarray (C,)
        The classes' DF MRFT frequencies at the grid's beta, rad/s.
    kp, kd, N : ndarray (C,)
        The classes' table gains (K = 1) and filters (rad/s).
    pairs : (class index, point index) arrays or None
        The pairs to evaluate; None: all C x P.
    kick : bool
        Step semantics of the ISE.
    scaling : str
        Gain estimate (``estimated_gain``).

    Returns
    -------
    ndarray: (C, P) for all pairs, else (len(pairs[0]),); in [1, J_MAX].
    """
    kp, kd, N = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (kp, kd, N))
    C = kp.size
    P = np.asarray(point_ise).size
    if pairs is None:
        ci, pj = (a.ravel() for a in np.meshgrid(np.arange(C), np.arange(P), indexing="ij"))
    else:
        ci, pj = (np.asarray(a, dtype=np.int64).reshape(-1) for a in pairs)
    tp = _take(point_params, pj)
    K_hat = estimated_gain(family, np.asarray(point_omega, dtype=np.float64).reshape(-1)[pj], tp,
                           _take(class_params, ci), np.asarray(class_omega, dtype=np.float64).reshape(-1)[ci], scaling)
    Q = controller_ise(family, rate_hz, tp, kp[ci] / K_hat, kd[ci] / K_hat, N[ci], kick=kick)
    J = _clip_j(Q, np.asarray(point_ise, dtype=np.float64).reshape(-1)[pj])
    return J.reshape(C, P) if pairs is None else J


def table_j_matrix(family: str, rate_hz: float, class_params: dict, kp, kd, N, ise, omega,
                   kick: bool = False, scaling: str = "mrft") -> np.ndarray:
    """``J_ij`` between the classes of a table, (n, n), rows: class answered, columns: true class.

    ``class_params`` (unit-gain classes), ``kp``, ``kd``, ``N`` (rad/s), ``ise`` (their optima) and
    ``omega`` (DF MRFT frequencies at the grid's beta), arrays (n,). The diagonal is 1 (to rounding).
    """
    return j_of_points(family, rate_hz, {**class_params, "K": 1.0}, omega, ise, class_params, omega, kp, kd, N,
                       kick=kick, scaling=scaling)
