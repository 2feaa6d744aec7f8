"""Search of the rule's (beta, pm) minimizing the worst-case ISE deterioration.

For a sample of processes of a loop's box, the deterioration of the rule at
``(beta, pm)`` is ``Q(rule controller, G) / Q(best PD, G)`` where the best PD
minimizes the step ISE over ``(kp, kd)`` (Nelder-Mead in log coordinates, the
derivative filter at 10x the process's MRFT frequency at the default beta).
The search takes the minimax over a (beta, pm) grid in the authors' bounds
(beta in [-0.9, -0.1], pm in [20, 90] deg), then refines around the best node.

Robust variant (``search_rule``, used per attitude class by the lateral grids): the
rule also takes a loop-gain scale ``s`` (``uavsim.tuning.rule``), and candidates are
ranked first by the share of a process sample their own-loop controllers keep
stable, then by the worst deterioration. The lateral loops need it: their MRFT
frequency sits on the closed attitude loop's resonance, so at ``s = 1`` no
``(beta, pm)`` in the bounds stabilizes the small-``T2`` part of the box over a
slow attitude class (phase margins above 20 deg add derivative gain at the
resonance and make it worse), while ``s`` of 0.5-0.7 stabilizes all of it.
The ISE-optimal PD of each process starts from the best node of a coarse
``(kp, Td)`` scan, so it also exists where the rule's gains are unstable.

    from uavsim.tuning.search import search_beta_pm
    res = search_beta_pm("altitude", n_processes=12)
    res["beta"], res["pm_deg"], res["worst_deterioration"]
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from scipy.optimize import minimize

from uavsim.errors import UserError
from uavsim.lumped.ise import step_ise_batch
from uavsim.lumped.params import RANGES, loop_family
from uavsim.tuning.rule import DEFAULT_BETA, TuningRule

__all__ = ["optimal_pd", "optimal_pd_batch", "rule_candidates", "rule_scores", "search_rule", "search_beta_pm"]


def optimal_pd(family: str, params: dict[str, float], N: float, omega_ref: float, x0: tuple[float, float]) -> tuple[float, float, float]:
    """ISE-optimal ``(kp, kd, Q)`` of one process at a fixed derivative filter N (rad/s)."""

    def f(z: np.ndarray) -> float:
        q = step_ise_batch(family, math.exp(z[0]), math.exp(z[1]), N, omega_ref, n=1500, **params)[0]
        return math.log(q) if np.isfinite(q) else 50.0

    res = minimize(f, np.log(x0), method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 400})
    return math.exp(res.x[0]), math.exp(res.x[1]), math.exp(res.fun)


def _worst(family: str, P: list[dict], q_opt: np.ndarray, beta: float, pm: float) -> float:
    try:
        rule = TuningRule(beta, pm)
        _ = rule.constants
    except Exception:
        return math.inf
    worst = 1.0
    for p, qo in zip(P, q_opt, strict=True):
        g = rule.gains_batch(family, **p)
        q = step_ise_batch(family, g["kp"], g["kd"], g["N"], g["omega"], n=1500, **p)[0]
        worst = max(worst, q / qo)
    return worst


def search_beta_pm(loop: str = "altitude", n_processes: int = 12, seed: int = 0,
                   betas: np.ndarray | None = None, pms: np.ndarray | None = None) -> dict[str, Any]:
    """Minimax (beta, pm) over a random sample of the loop's box (inner loops).

    Returns
    -------
    dict: ``beta``, ``pm_deg``, ``c1``, ``c3``, ``worst_deterioration`` (ratio),
    ``table`` (beta, pm, worst) for every node, ``n_processes``, ``time_s``.
    """
    t0 = time.time()
    fam = loop_family(loop)
    box = RANGES[fam]
    rng = np.random.default_rng(seed)
    keys = ("T_prop", "T1", "tau")
    lo = np.log([box[k][0] for k in keys])
    hi = np.log([box[k][1] for k in keys])
    X = np.exp(lo + (hi - lo) * rng.random((n_processes, 3)))
    # include the box corners that bound the frequency range
    X = np.vstack([X, [box[k][0] for k in keys], [box[k][1] for k in keys]])
    P = [{"K": 1.0, **dict(zip(keys, x, strict=True))} for x in X]
    ref_rule = TuningRule(DEFAULT_BETA, 20.0)
    q_opt = []
    for p in P:
        g = ref_rule.gains_batch(fam, **p)
        kp, kd, q = optimal_pd(fam, p, float(g["N"][0]), float(g["omega"][0]), (float(g["kp"][0]), float(g["kd"][0])))
        q_opt.append(q)
    q_opt = np.array(q_opt)
    betas = np.arange(-0.9, -0.09, 0.1) if betas is None else betas
    pms = np.arange(20.0, 91.0, 10.0) if pms is None else pms
    table = [(float(b), float(m), _worst(fam, P, q_opt, b, m)) for b in betas for m in pms]
    b0, m0, _ = min(table, key=lambda r: r[2])
    fine = [(float(b), float(m), _worst(fam, P, q_opt, b, m))
            for b in np.clip(b0 + np.arange(-0.08, 0.081, 0.02), -0.95, -0.05)
            for m in np.clip(m0 + np.arange(-8.0, 8.1, 2.0), 5.0, 90.0)]
    b, m, worst = min(table + fine, key=lambda r: r[2])
    c1, c3 = TuningRule(b, m).constants
    return {"loop": fam, "beta": b, "pm_deg": m, "c1": c1, "c3": c3, "worst_deterioration": worst,
            "n_processes": len(P), "seed": seed, "table": table + fine, "time_s": round(time.time() - t0, 1),
            "worst_at_default": _worst(fam, P, q_opt, DEFAULT_BETA, 20.0)}


def _pick(params: dict[str, Any], i: int) -> dict[str, Any]:
    """Process ``i`` of a batch of process parameters (scalars are shared)."""
    return {k: (np.asarray(v).reshape(-1)[i] if np.size(v) > 1 else v) for k, v in params.items()}


def optimal_pd_batch(family: str, params: dict[str, Any], N: np.ndarray, omega_ref: np.ndarray,
                     gain_ref: np.ndarray) -> np.ndarray:
    """ISE-optimal step ISE of B processes at fixed derivative filters, (B,).

    Parameters
    ----------
    family : str
        Loop family.
    params : dict
        Process parameters (arrays (B,) or scalars, with ``K``).
    N, omega_ref : ndarray (B,)
        Derivative filter and frequency-grid centre of each process, rad/s (e.g. 10x and 1x
        its MRFT frequency).
    gain_ref : ndarray (B,)
        ``|G(j omega_ref)|`` of each process (output/command); the scan's gains are relative to it.

    Returns
    -------
    ndarray (B,): the minimal ISE, output^2 s (inf if no scanned PD is stable).

    Each process's Nelder-Mead (``optimal_pd``) starts from the best node of a
    15 x 15 scan of ``kp |G| in [0.01, 3]`` and ``Td omega_ref in [0.02, 10]``: a rule
    controller is no safe start where the rule itself is unstable.
    """
    c, d = np.meshgrid(np.geomspace(0.01, 3.0, 15), np.geomspace(0.02, 10.0, 15), indexing="ij")
    c, d = c.ravel(), d.ravel()
    q_opt = np.empty(len(N))
    for i in range(len(N)):
        pi = _pick(params, i)
        kp0 = c / gain_ref[i]
        kd0 = kp0 * d / omega_ref[i]
        q = step_ise_batch(family, kp0, kd0, N[i], omega_ref[i], n=1500, **pi)
        j = int(np.argmin(q))
        if not np.isfinite(q[j]):
            q_opt[i] = math.inf
            continue
        _, _, q_opt[i] = optimal_pd(family, pi, float(N[i]), float(omega_ref[i]), (float(kp0[j]), float(kd0[j])))
    return q_opt


def rule_candidates(betas, pms, scales) -> list[tuple[float, float, float]]:
    """Valid ``(beta, pm_deg, gain_scale)`` nodes of a grid (the derivative lead must be in (0, 90) deg)."""
    out = []
    for b in betas:
        for m in pms:
            lead = math.radians(m) - math.asin(b)
            if 0.0 < lead < math.pi / 2:
                out += [(round(float(b), 4), round(float(m), 4), round(float(s), 4)) for s in scales]
    return out


def rule_scores(family: str, params: dict[str, Any], q_opt: np.ndarray, candidates: list[tuple[float, float, float]],
                cache: dict | None = None) -> list[list[float]]:
    """Stable share and worst deterioration of rule candidates over a process sample.

    Parameters
    ----------
    family : str
        Loop family.
    params : dict
        P processes (arrays (P,) or scalars, with ``K``).
    q_opt : ndarray (P,)
        Reference ISE of each process (``optimal_pd_batch``); NaN where a process only
        counts for stability.
    candidates : list of (beta, pm_deg, gain_scale)
    cache : dict or None
        Rule gains at ``gain_scale`` 1 per ``(beta, pm)`` (the MRFT prediction is the costly
        part); pass the same dict to later calls on the same processes.

    Returns
    -------
    list of ``[beta, pm_deg, gain_scale, stable_fraction, worst_deterioration]`` (worst over the
    processes with a reference ISE that the candidate stabilizes; inf if none).
    """
    cache = {} if cache is None else cache
    has_ref = np.isfinite(q_opt)
    rows = []
    for b, m, sc in candidates:
        if (b, m) not in cache:
            try:
                cache[(b, m)] = TuningRule(b, m).gains_batch(family, **params)
            except UserError:  # no MRFT oscillation for part of the sample at this beta
                cache[(b, m)] = None
        g = cache[(b, m)]
        if g is None:
            rows.append([b, m, sc, 0.0, math.inf])
            continue
        # the gain scale multiplies kp and kd alike (c1 scales, c3 does not)
        q = step_ise_batch(family, sc * g["kp"], sc * g["kd"], g["N"], g["omega"], n=1500, **params)
        fin = np.isfinite(q) & has_ref
        worst = float(np.max(q[fin] / q_opt[fin])) if fin.any() else math.inf
        rows.append([b, m, sc, float(np.mean(np.isfinite(q))), worst])
    return rows


def _best(rows: list[list[float]], tol: float) -> list[float]:
    """Largest stable share (within ``tol``), then the smallest worst deterioration (ties: the larger
    gain scale)."""
    top = max(r[3] for r in rows)
    return min((r for r in rows if r[3] >= top - tol), key=lambda r: (r[4], -r[2]))


#: coarse candidate grid of the robust search: the authors' (beta, pm) bounds, gain scale in [0.25, 1]
SEARCH_BETAS = (-0.9, -0.7, -0.5, -0.3, -0.1)
SEARCH_PMS = (20.0, 35.0, 50.0, 65.0, 80.0)
SEARCH_SCALES = (1.0, 0.7, 0.5, 0.35, 0.25)


def search_rule(family: str, params: dict[str, Any], q_opt: np.ndarray, tol: float = 0.0,
                betas=SEARCH_BETAS, pms=SEARCH_PMS, scales=SEARCH_SCALES) -> dict[str, Any]:
    """Robust minimax ``(beta, pm, gain_scale)`` over a process sample (see module docstring).

    A coarse grid (default: beta in [-0.9, -0.1], pm in [20, 80] deg, scale in [0.25, 1]),
    then one refinement around the best node (beta +-0.05, pm +-7.5 deg,
    scale x0.85^{-1, 0, 1}), all inside the bounds; ranked by ``_best``.

    Parameters
    ----------
    family, params, q_opt : see ``rule_scores``.
    tol : float
        Stable-share tolerance of the ranking (0: the most stable candidates only).

    Returns
    -------
    dict: ``beta``, ``pm_deg``, ``gain_scale``, ``stable_fraction``, ``worst_deterioration``
    (None if infinite), ``n_evaluated``, ``top`` (the 5 best rows by stable share then worst
    deterioration, as ``rule_scores``).
    """
    cache: dict = {}
    rows = rule_scores(family, params, q_opt, rule_candidates(betas, pms, scales), cache)
    b0, m0, s0 = _best(rows, tol)[:3]
    fine = rule_candidates(np.clip(b0 + np.array([-0.05, 0.0, 0.05]), -0.9, -0.1),
                           np.clip(m0 + np.array([-7.5, 0.0, 7.5]), 20.0, 90.0),
                           np.clip(s0 * np.array([0.85, 1.0, 1 / 0.85]), 0.2, 1.0))
    seen = {tuple(r[:3]) for r in rows}
    # clipping at the bounds repeats nodes: each is scored once
    rows += rule_scores(family, params, q_opt, [c for c in dict.fromkeys(fine) if c not in seen], cache)
    b, m, sc, frac, worst = _best(rows, tol)
    ranked = sorted(rows, key=lambda r: (-r[3], r[4]))[:5]
    return {"beta": b, "pm_deg": m, "gain_scale": sc, "stable_fraction": frac,
            "worst_deterioration": worst if math.isfinite(worst) else None, "n_evaluated": len(rows),
            # JSON has no infinity: an unusable candidate's worst deterioration is null
            "top": [[*r[:4], r[4] if math.isfinite(r[4]) else None] for r in ranked]}
