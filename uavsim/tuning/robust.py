"""One PD for several candidate models: the least expected J at the control rate.

When a cycle does not tell a few models apart (identification's best fits, or a
class and its neighbours), the gains to answer are those of least expected
relative sensitivity over them,

    E(C) = sum_j w_j Q(s_j C, G_j) / Q*_j

with ``Q`` the exact sampled ISE (``uavsim.lumped.sampled``), ``Q*_j`` model ``j``'s
own optimum at the rate (``uavsim.tuning.optimal``), ``w_j`` the models' weights
and ``s_j`` a gain factor per model (1 for fitted models with their own K; for a
table class answered on a neighbour, ``1 / K_hat`` of identification's gain
estimate). ``E`` is minimized over ``(kp, kd)`` by the batched Newton method of
``uavsim.tuning.optimal`` (``minimize_log`` on ``log E``), from the candidate
model optimum of least ``E`` (halved until it holds every model, if none does).
An answer is stable on every model by construction (an unstable model makes
``E`` infinite), and never worse than the best candidate's own optimum.

    from uavsim.tuning.robust import robust_gains
    r = robust_gains("altitude", 200.0, models={"K": [1, 1], "T_prop": [0.1, 0.12], "T1": [0.8, 0.8],
                     "tau": [0.02, 0.03]}, group=[0, 0], N=[60.0, 60.0])
    r["kp"], r["kd"], r["expected_J"]        # one answer per group
"""

from __future__ import annotations

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.params import loop_family
from uavsim.lumped.sampled import lift, sampled_ise
from uavsim.tuning.optimal import DEFAULT_RATE_HZ, minimize_log, optimal_gains

__all__ = ["robust_gains"]


def robust_gains(family: str, rate_hz: float = DEFAULT_RATE_HZ, *, models: dict, group, N, weights=None,
                 scale=None, q_opt=None, kp_opt=None, kd_opt=None, kick: bool = False) -> dict[str, np.ndarray]:
    """The PD of least expected J over each group of candidate models (module docstring).

    Parameters
    ----------
    family, rate_hz : str, float
        Loop family and control rate (Hz).
    models : dict
        M candidate processes (arrays (M,) or scalars, with ``K``), as ``uavsim.lumped.sampled.lift``.
    group : int array (M,)
        The problem each model belongs to (0..G-1); one answer per group.
    N : float or ndarray (G,)
        The answer's derivative filter per group, rad/s.
    weights : ndarray (M,) or None
        Weight of each model in its group (normalized per group); default equal.
    scale : ndarray (M,) or None
        Gain factor applied to the answer on each model (default 1).
    q_opt, kp_opt, kd_opt : ndarray (M,) or None
        Each model's optimal ISE and gains (at its own filter) if known; else computed here.
    kick : bool
        Step semantics of the ISE.

    Returns
    -------
    dict of (G,) arrays: ``kp``, ``kd`` (for ``scale`` 1), ``expected_J``, ``start_J`` (the best
    candidate optimum's), ``iterations``, ``converged``.
    """
    fam = loop_family(family)
    group = np.asarray(group, dtype=np.int64).reshape(-1)
    M = group.size
    G = int(group.max()) + 1 if M else 0
    if M == 0 or np.any(group < 0) or set(np.unique(group)) != set(range(G)):
        raise UserError("robust_gains needs group indices 0..G-1, each with at least one model")
    proc = lift(fam, rate_hz, **models)
    if proc.B != M:
        proc = proc.take(np.zeros(M, dtype=np.int64))
    w = np.ones(M) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.size != M or np.any(~np.isfinite(w)) or np.any(w < 0):
        raise UserError("weights must be M finite numbers >= 0")
    tot = np.bincount(group, weights=w, minlength=G)
    if np.any(tot <= 0):
        raise UserError("every group needs a positive weight")
    w = w / tot[group]
    s = np.ones(M) if scale is None else np.broadcast_to(np.asarray(scale, dtype=np.float64), (M,))
    Ng = np.broadcast_to(np.asarray(N, dtype=np.float64), (G,))
    if q_opt is None or kp_opt is None or kd_opt is None:
        o = optimal_gains(fam, rate_hz, kick=kick, **models)
        q_opt, kp_opt, kd_opt = o.ise, o.kp, o.kd
    q_opt, kp_opt, kd_opt = (np.broadcast_to(np.asarray(v, dtype=np.float64), (M,)) for v in (q_opt, kp_opt, kd_opt))
    if not np.all(np.isfinite(q_opt)):
        raise UserError("every candidate model needs a stable optimum")
    members = [np.flatnonzero(group == g) for g in range(G)]

    def expected(gi: np.ndarray, th: np.ndarray) -> np.ndarray:
        """E of answers ``th`` (m, 2) for groups ``gi`` (m,): every member model of each, one batch."""
        rows = np.concatenate([members[g] for g in gi])
        ans = np.repeat(np.arange(len(gi)), [len(members[g]) for g in gi])
        with np.errstate(over="ignore", invalid="ignore"):
            q = sampled_ise(proc.take(rows), s[rows] * np.exp(th[ans, 0]), s[rows] * np.exp(th[ans, 1]),
                            Ng[gi][ans], kick=kick)
        return np.bincount(ans, weights=np.where(np.isfinite(q), w[rows] * q / q_opt[rows], np.inf),
                           minlength=len(gi))

    # start: each member's own optimum (as the group's answer: divided by its scale), the best E wins
    cand_g = group
    cand = np.column_stack([np.log(kp_opt / s), np.log(kd_opt / s)])
    with np.errstate(invalid="ignore"):
        e = expected(cand_g, cand)
    th0 = np.empty((G, 2))
    e0 = np.empty(G)
    for g in range(G):
        j = members[g][np.argmin(e[members[g]])]
        th0[g], e0[g] = cand[j], e[j]
    for _ in range(12):  # none holds every model: halve the gains until one does
        bad = ~np.isfinite(e0)
        if not bad.any():
            break
        th0[bad] -= np.log(2.0)
        e0[bad] = expected(np.flatnonzero(bad), th0[bad])
    if not np.all(np.isfinite(e0)):
        raise UserError("no PD found that is stable on every candidate model")

    def logf(gi, th):
        with np.errstate(divide="ignore"):
            return np.log(expected(gi, th))

    r = minimize_log(logf, th0)
    return {"kp": np.exp(r["th"][:, 0]), "kd": np.exp(r["th"][:, 1]), "expected_J": np.exp(r["f"]),
            "start_J": e0, "iterations": r["iterations"], "converged": r["converged"]}
