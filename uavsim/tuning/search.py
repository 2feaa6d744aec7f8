"""Search of the rule's (beta, pm) minimizing the worst-case ISE deterioration.

For a sample of processes of a loop's box, the deterioration of the rule at
``(beta, pm)`` is ``Q(rule controller, G) / Q(best PD, G)`` where the best PD
minimizes the step ISE over ``(kp, kd)`` (Nelder-Mead in log coordinates, the
derivative filter at 10x the process's MRFT frequency at the default beta).
The search takes the minimax over a (beta, pm) grid in the authors' bounds
(beta in [-0.9, -0.1], pm in [20, 90] deg), then refines around the best node.

The lateral rules are chosen per attitude class at the control rate by
``uavsim.tuning.lateral_grid.choose_rule`` (exact sampled ISE).

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

from uavsim.lumped.ise import step_ise_batch
from uavsim.lumped.params import RANGES, loop_family
from uavsim.tuning.rule import DEFAULT_BETA, TuningRule

__all__ = ["optimal_pd", "search_beta_pm"]


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
