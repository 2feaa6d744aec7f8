"""Figures of a grid's lookup table at the control rate, against the ISE optimum.

Everything here is a relative sensitivity ``J = Q(answer) / Q(optimal PD of the
true process)`` at the table's control rate (``uavsim.tuning.sensitivity``):

* the table's rule check: the grid's homogeneous rule on each class against the
  class's optimum (``rule_J``);
* neighbour J: the table's symmetrized J between neighbouring classes across and
  within ``Omega`` levels (``uavsim.tuning.grid.neighbour_pairs``), against the
  paper's J = 1.10 design, for the classes' optima and for their robust answers
  (``robust_*``; ``robust_own_J``: what the robust answer costs its own class);
* off-grid figures on seeded random processes of the box (each with its own
  optimum at the rate): coverage (the table gains of the nearest class, by
  log-box distance, and of the best class, what a perfect J-trained classifier
  would answer, both scaled by the gain identification estimates; optimal and
  robust gains), and the
  controls: the rule on the true process, the rule detuned x0.85, the optimum
  itself detuned x0.85 (a metric that did not punish it would be broken), and
  the ratio of the optimal ``kp`` to the rule's.

    from uavsim.tuning.table_report import table_figures
    rep = table_figures(load_grid("altitude"), load_table("altitude"), n_points=300, seed=2)
    rep["coverage"]["nearest"]["p95"], rep["neighbour_J_across_levels"]["median"]
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
from uavsim.lumped.params import loop_family
from uavsim.tuning.grid import (
    BOX_AXES,
    TARGETS,
    box_sample,
    class_process_params,
    log_box,
    neighbour_pairs,
)
from uavsim.tuning.jmatrix import J_MAX, symmetrize
from uavsim.tuning.optimal import optimal_gains
from uavsim.tuning.sensitivity import controller_ise, j_of_points

__all__ = ["table_figures", "j_stats", "neighbour_j", "point_j", "DETUNE"]

#: the detuning control's factor on kp and kd
DETUNE = 0.85


def j_stats(J: np.ndarray) -> dict[str, float]:
    """Median, p95, max and the count of unstable answers (J at ``J_MAX`` or inf) of J values."""
    J = np.asarray(J, dtype=np.float64).ravel()
    if J.size == 0:
        return {"n": 0, "median": math.nan, "p95": math.nan, "max": math.nan, "unstable": 0}
    bad = ~np.isfinite(J) | (J >= J_MAX)
    Jf = np.where(bad, J_MAX, J)
    return {"n": int(J.size), "median": float(np.median(Jf)), "p95": float(np.quantile(Jf, 0.95)),
            "max": float(Jf.max()), "unstable": int(bad.sum())}


def _ratio(q: np.ndarray, q_opt: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        J = q / q_opt
    return np.where(np.isfinite(J), np.maximum(J, 1.0), J_MAX)


def neighbour_j(grid, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J between neighbouring classes (``neighbour_pairs``), symmetrized: across levels, within a level."""
    Js = symmetrize(J)
    across, within = neighbour_pairs(grid)
    return (Js[across[:, 0], across[:, 1]] if len(across) else np.zeros(0),
            Js[within[:, 0], within[:, 1]] if len(within) else np.zeros(0))


def _cat(dicts: list[dict[str, Any]], sizes: list[int]) -> dict[str, np.ndarray]:
    """Concatenate process-parameter dicts (scalars broadcast to each part's size)."""
    return {k: np.concatenate([np.broadcast_to(np.asarray(d[k], dtype=np.float64), (n,)) for d, n in
                               zip(dicts, sizes, strict=True)]) for k in dicts[0]}


def point_j(fam: str, groups: list[tuple], n: int, seed: int) -> dict[str, np.ndarray]:
    """J of the answers and controls on ``n`` random box processes per group (module docstring).

    ``groups``: (grid, table, attitude or None) per grid (the lateral sub-grids); the points of
    group ``k`` are drawn with seed ``seed + k`` and judged against that group's classes only.
    All groups are evaluated in a few batched calls. Returns arrays (n * len(groups),).
    """
    rate = groups[0][1].rate_hz
    lo, hi = log_box(fam)
    X, pp, cls, near, rules = [], [], [], [], []
    c0 = 0
    for k, (g, t, att) in enumerate(groups):
        x = box_sample(fam, np.random.default_rng(seed + k), n)
        xc = np.column_stack([np.asarray(g.params[a], float) for a in BOX_AXES[fam]])
        X.append(x)
        pp.append(class_process_params(fam, x, att))
        cls.append(class_process_params(fam, xc, att))
        zp, zc = (np.log(x) - lo) / (hi - lo), (np.log(xc) - lo) / (hi - lo)
        near.append(c0 + np.argmin(((zp[:, None, :] - zc[None]) ** 2).sum(-1), axis=1))
        rules.append(g.rule)
        c0 += t.n
    G = len(groups)
    P = n * G
    pp = {"K": 1.0, **_cat(pp, [n] * G)}
    cp = _cat(cls, [t.n for _, t, _ in groups])
    tabs = [t for _, t, _ in groups]
    kp, kd, N, om = (np.concatenate([getattr(t, a) for t in tabs]) for a in ("kp", "kd", "N", "omega"))
    # the optimum of every point, one batch per distinct rule (it sets the filter's frequency)
    out = {a: np.empty(P) for a in ("ise", "kp", "kd", "N", "omega", "rule_kp", "rule_kd")}
    keys = [(r.beta, r.pm_deg, r.gain_scale) for r in rules]
    for key in dict.fromkeys(keys):
        idx = np.concatenate([np.arange(k * n, (k + 1) * n) for k in range(G) if keys[k] == key])
        o = optimal_gains(fam, rate, rule=rules[keys.index(key)], **{a: v[idx] if np.size(v) > 1 else v
                                                                     for a, v in pp.items()})
        for a in out:
            out[a][idx] = getattr(o, a)
    # class i of group k judged on the points of group k only
    ci = np.concatenate([np.repeat(np.arange(sum(t.n for t in tabs[:k]), sum(t.n for t in tabs[:k + 1])), n)
                         for k in range(G)])
    pj = np.concatenate([np.tile(np.arange(k * n, (k + 1) * n), tabs[k].n) for k in range(G)])
    near = np.concatenate(near)
    res: dict[str, np.ndarray] = {}
    rkp, rkd = (np.concatenate([getattr(t, a) for t in tabs]) for a in ("robust_kp", "robust_kd"))
    for kind, (gkp, gkd) in (("", (kp, kd)), ("robust_", (rkp, rkd))):
        Jp = j_of_points(fam, rate, pp, out["omega"], out["ise"], cp, om, gkp, gkd, N, pairs=(ci, pj),
                         scaling=tabs[0].scaling)
        best = np.full(P, np.inf)
        np.minimum.at(best, pj, Jp)
        lookup = {(int(a), int(b)): v for a, b, v in zip(ci, pj, Jp, strict=True)}
        res[kind + "best"] = best
        res[kind + "nearest"] = np.array([lookup[(int(near[j]), j)] for j in range(P)])
    N_rule = DERIVATIVE_FILTER_RATIO * out["omega"]  # the rule's own filter, uncapped
    q_rule = controller_ise(fam, rate, pp, out["rule_kp"], out["rule_kd"], N_rule)
    q_rule85 = controller_ise(fam, rate, pp, DETUNE * out["rule_kp"], DETUNE * out["rule_kd"], N_rule)
    q_opt85 = controller_ise(fam, rate, pp, DETUNE * out["kp"], DETUNE * out["kd"], out["N"])
    return {"ok": np.isfinite(out["ise"]), **res, "rule": _ratio(q_rule, out["ise"]), "rule_x085": _ratio(q_rule85, out["ise"]),
            "optimum_x085": _ratio(q_opt85, out["ise"]), "kp_over_rule": out["kp"] / out["rule_kp"]}


def _summarize(pts: dict[str, np.ndarray]) -> dict[str, Any]:
    ok = pts["ok"]
    out: dict[str, Any] = {"n_points": int(ok.size), "n_without_optimum": int((~ok).sum())}
    out["coverage"] = {k: j_stats(pts[k][ok]) for k in ("nearest", "best", "robust_nearest", "robust_best")}
    out["controls"] = {k: j_stats(pts[k][ok]) for k in ("rule", "rule_x085", "optimum_x085")}
    r = pts["kp_over_rule"][ok]
    out["kp_optimal_over_rule"] = {"min": float(r.min()), "median": float(np.median(r)), "max": float(r.max())} if r.size else {}
    return out


def _min(x: np.ndarray) -> float:
    return float(np.min(x)) if len(x) else math.nan


def table_figures(grid, table, n_points: int = 300, seed: int = 1) -> dict[str, Any]:
    """The table's figures (module docstring) for a grid and its table.

    Parameters
    ----------
    grid : Grid
    table : OptimalTable
        The grid's table (same hash).
    n_points : int
        Random box processes (lateral: in all, shared evenly over the sub-grids, at least 4 each).
    seed : int
        Seed of the random processes (lateral: ``seed + attitude class``).

    Returns
    -------
    dict: ``rate_hz``, ``rule_J`` (the grid's rule on its classes), ``neighbour_J_across_levels``,
    ``neighbour_J_within_level`` (with ``target`` 1.10), ``coverage`` (``nearest``, ``best``),
    ``controls`` (``rule``, ``rule_x085``, ``optimum_x085``), ``kp_optimal_over_rule``, ``time_s``.
    """
    t0 = time.time()
    fam = loop_family(grid.loop)
    if table.grid_hash != grid.hash:
        from uavsim.errors import UserError

        raise UserError(f"the {fam} table belongs to another grid (hash {table.grid_hash[:12]})")
    pairs = [(grid, table, None)] if not grid.sub else [
        (g, t, t.attitude) for g, t in zip(grid.sub, table.sub, strict=True)]
    per = n_points if not grid.sub else max(4, int(math.ceil(n_points / len(grid.sub))))
    fig: dict[str, list] = {k: [] for k in ("across", "within", "r_across", "r_within", "rule_J", "robust_own")}
    for g, t, _ in pairs:
        for pre, J in (("", t.J), ("r_", t.J_robust)):
            a, w = neighbour_j(g, J)
            fig[pre + "across"].append(a)
            fig[pre + "within"].append(w)
        fig["rule_J"].append(_ratio(t.rule_ise, t.ise))
        fig["robust_own"].append(np.diag(t.J_robust))
    f = {k: np.concatenate(v) for k, v in fig.items()}

    def nb(x):
        return {**j_stats(x), "min": _min(x), "target": TARGETS["J"]}

    rep: dict[str, Any] = {"loop": fam, "rate_hz": table.rate_hz, "table_hash": table.hash, "seed": seed,
                           "n_classes": int(len(f["rule_J"])), "rule_J": j_stats(f["rule_J"]),
                           "neighbour_J_across_levels": nb(f["across"]), "neighbour_J_within_level": nb(f["within"]),
                           "robust_own_J": j_stats(f["robust_own"]),
                           "robust_neighbour_J_across_levels": nb(f["r_across"]),
                           "robust_neighbour_J_within_level": nb(f["r_within"])}
    rep.update(_summarize(point_j(fam, pairs, per, seed)))
    rep["time_s"] = round(time.time() - t0, 1)
    return rep
