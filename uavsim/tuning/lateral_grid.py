"""Lateral class grids over the attitude loop as flown, spaced by the table's J.

The lateral loop is identified and tuned after the attitude loop, which by then flies its
attitude class's table PD (``uavsim.tuning.table``) at the control rate. Each attitude class
gets a sub-grid of the ``(T2, tau_out)`` box designed on exactly that loop:

* **The loop.** The attitude loop is closed by the attitude table's PD, sampled at the control
  rate (200 Hz) with a zero-order hold. Every frequency-domain quantity sees it
  (``att_rate_hz``, ``uavsim.lumped.lateral.attitude_closed_loop_sampled``): the MRFT frequency
  (the attitude PD reads the relay's output only at its samples, so the harmonic balance is on
  the sampled response, the command's hold included), the magnitudes of the gain estimate and
  the rule's gains. The cycles stored (``omega``, ``amplitude``) are exact relay simulations of
  the lifted sampled loop (``uavsim.lumped.lateral.sampled_relay_cycle``). At the classes'
  MRFT frequencies the continuous attitude loop is off by up to 28% in magnitude and 13 deg in
  phase (docs/results/lateral-grid.md).
* **The relay's beta** (``choose_beta``): NP-MRFT needs ``beta >= -1 + sin(2 pi tau_obs / T0)``.
  Each attitude class takes the lowest beta, from -0.73 (the inner loops') up in steps of
  0.05, at which an observation time of ``TAU_OBS`` (0.03 s, the recipes') fits the fastest
  cycle of its box. Lower beta needs fewer classes for the same J; fast attitude classes make
  lateral cycles of 0.15-0.3 s and need beta up to about -0.2.
* **The classes** (``design_classes``): a sample of the box (scrambled Sobol, plus its corners)
  is optimized at the control rate (``uavsim.tuning.optimal``); J of point ``c``'s optimum on
  point ``p`` is the exact sampled ISE of those gains divided by the gain identification
  estimates (``"response"`` scaling, ``uavsim.tuning.sensitivity``: the gain fitted at ``p``'s
  own cycle frequency, as ``uavsim.ident`` fits it), over ``p``'s optimum. Classes
  are taken greedily, the point whose optimum brings the most sample points within
  ``COVER_J`` = 1.05 first, until every point has a class within 1.05: neighbouring classes
  end about J = 1.10 apart (the paper's design), and the class count follows from the J
  landscape instead of a budget. J is evaluated between points whose MRFT frequencies are
  within ``OMEGA_WINDOW`` (beyond, the optima are unstable on each other or far apart).
  The lateral optima are fragile (gain margins 1.03-1.3): J is not a function of the
  MRFT frequency alone, so the classes are a two-dimensional cover, not ``Omega`` levels.
* **Neighbours** (``Grid.neighbours``): the two classes of least J on each sample point where the
  second is within ``NEIGHBOUR_J`` -- the classes a classifier confuses there. The table's
  robust answer of a class holds its neighbours (``uavsim.tuning.table.neighbourhoods``).
* **J** of the sub-grid (the training loss's) is the table's J of its robust answers: class
  ``i``'s robust gains, scaled by the gain estimate, on class ``j`` against ``j``'s optimum.
* **The rule** ``(beta, pm, gain_scale)`` still gives each class's ``kp``/``kd`` (the table's
  optimization starts from it, and the table reports it): at the chosen beta, the
  ``(pm, gain_scale)`` that keeps the most of the sample stable at the control rate, then
  has the least worst J (``choose_rule``, exact sampled ISE).

    from uavsim.tuning.lateral_grid import build_lateral
    g = build_lateral(seed=0)                       # 48 sub-grids (tens of minutes)
    g.lateral(5).beta, g.lateral(5).neighbours
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.lateral import sampled_relay_cycle
from uavsim.tuning.grid import (
    GRID_VERSION,
    Grid,
    attitude_of,
    box_sample,
    class_process_params,
    load_grid,
    log_box,
)
from uavsim.tuning.jmatrix import J_MAX
from uavsim.tuning.optimal import DEFAULT_RATE_HZ, optimal_gains
from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule
from uavsim.tuning.sensitivity import j_of_points

__all__ = ["TAU_OBS", "COVER_J", "NEIGHBOUR_J", "OMEGA_WINDOW", "N_SAMPLES", "beta_min", "choose_beta", "cover",
           "class_neighbours", "choose_rule", "design_subgrid", "build_lateral"]

#: NP-MRFT observation time the relay's beta must allow on the fastest cycle, s (the recipes')
TAU_OBS = 0.03
#: every sample point has a class whose optimum is within this J of its own
COVER_J = 1.05
#: two classes are neighbours where both are within this J on a sample point
NEIGHBOUR_J = 1.25
#: J is evaluated between points whose MRFT frequencies are within this log ratio
OMEGA_WINDOW = 0.25
#: box sample of each sub-grid's design (scrambled Sobol points; the 4 corners are added)
N_SAMPLES = 128
#: beta candidates: from the inner loops' up in steps of 0.05
_BETAS = np.round(np.arange(DEFAULT_BETA, -0.04, 0.05), 2)
#: (pm, gain_scale) candidates of the lateral rule
_PMS = (20.0, 35.0, 50.0, 65.0, 80.0)
_SCALES = (1.0, 0.7, 0.5, 0.35, 0.25)
#: sample points the rule is scored on
_N_RULE = 40


#: the gain estimate the cover's J and the table's J assume (``uavsim.tuning.sensitivity.SCALINGS``):
#: identification's, fitted at each process's own cycle frequency
GAIN_SCALING = "response"


def beta_min(tau_obs: float, period) -> np.ndarray:
    """NP-MRFT's lowest beta for an observation time and a cycle period: ``-1 + sin(2 pi tau_obs / T0)``."""
    x = np.minimum(2.0 * math.pi * tau_obs / np.asarray(period, dtype=float), math.pi / 2)
    return -1.0 + np.sin(x)


def _params(X: np.ndarray, att: dict) -> dict[str, Any]:
    return {"K": 1.0, **class_process_params("lateral", X, att)}


def _df_omega(X: np.ndarray, att: dict, beta: float) -> np.ndarray:
    from uavsim.lumped.frequency import mrft_prediction_batch

    return mrft_prediction_batch("lateral", beta, 1.0, **_params(X, att))[0]


def choose_beta(att: dict, X: np.ndarray, tau_obs: float = TAU_OBS) -> dict[str, Any]:
    """The relay's beta over one attitude class (module docstring).

    Parameters
    ----------
    att : dict
        The attitude class and its PD (``uavsim.tuning.grid.attitude_of``, with ``rate_hz``).
    X : ndarray (P, 2)
        Box sample ``(T2, tau_out)`` whose fastest cycle sets the bound.
    tau_obs : float
        Observation time to allow, s.

    Returns
    -------
    dict: ``beta``, ``T0_min`` (s, the fastest DF period at it), ``beta_min`` (the bound there),
    ``feasible`` (False: even the last candidate falls short; it is taken).
    """
    # the fastest points at the inner loops' beta stay the fastest ones near it
    w0 = _df_omega(X, att, float(_BETAS[0]))
    fast = X[np.argsort(-np.nan_to_num(w0, nan=0.0))[:8]]
    for b in _BETAS:
        T0 = float(np.min(2.0 * math.pi / _df_omega(fast, att, float(b))))
        bm = float(beta_min(tau_obs, T0))
        if b >= bm - 1e-12:
            return {"beta": float(b), "T0_min": T0, "beta_min": bm, "feasible": True, "tau_obs": tau_obs}
    return {"beta": float(_BETAS[-1]), "T0_min": T0, "beta_min": bm, "feasible": False, "tau_obs": tau_obs}


def _sample(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` scrambled Sobol points of the log box, then its 4 corners, (n + 4, 2)."""
    from scipy.stats import qmc

    lo, hi = log_box("lateral")
    U = qmc.Sobol(2, scramble=True, seed=rng).random(n)
    X = np.exp(lo + (hi - lo) * U)
    return np.vstack([X, box_sample("lateral", rng, 0, corners=True)])


def cover(J: np.ndarray, cover_J: float = COVER_J) -> np.ndarray:
    """Greedy cover of sample points by their optima: the points taken as classes, in order, (n,).

    ``J`` (P, P): J of point ``c``'s answer (row) on point ``p`` (column), diagonal 1. The point
    whose answer brings the most uncovered points within ``cover_J`` is taken first (ties: the
    least excess J over those points), until every point is covered.
    """
    cov = J <= cover_J
    left = np.ones(J.shape[1], dtype=bool)
    classes: list[int] = []
    while left.any():
        gain = (cov & left).sum(axis=1)
        top = np.flatnonzero(gain == gain.max())
        cost = np.where(cov[top] & left, J[top], 0.0).sum(axis=1) - gain[top]
        c = int(top[np.argmin(cost)])
        classes.append(c)
        left &= ~cov[c]
    return np.array(classes, dtype=np.int64)


def class_neighbours(Jp: np.ndarray, Jc: np.ndarray, neighbour_J: float = NEIGHBOUR_J) -> np.ndarray:
    """Neighbouring class pairs ``(i, k)``, ``i < k``, (m, 2).

    ``Jp`` (n, P): the classes' answers on the sample points; ``Jc`` (n, n): on each other. On
    each point the two classes of least J are neighbours when the second is within
    ``neighbour_J``; a class left without (a corner) takes the class nearest it in J, either way.
    """
    n, P = Jp.shape
    pairs: set[tuple[int, int]] = set()
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    order = np.argsort(Jp, axis=0)
    b1, b2 = order[0], order[1]
    ok = Jp[b2, np.arange(P)] <= neighbour_J
    pairs |= {(int(min(i, k)), int(max(i, k))) for i, k in zip(b1[ok], b2[ok], strict=True)}
    Jn = np.minimum(Jc, Jc.T)
    np.fill_diagonal(Jn, np.inf)
    for i in range(n):
        if not any(i in p for p in pairs):
            k = int(np.argmin(Jn[i]))
            pairs.add((min(i, k), max(i, k)))
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


def _pair_J(att: dict, X: np.ndarray, o, rate_hz: float, window: float, pairs=None) -> np.ndarray:
    """J of every sample point's optimum on every other within ``window`` in log MRFT frequency, (P, P)
    (J_MAX outside); or on the ``pairs`` (answer, point) given."""
    P = len(X)
    lw = np.log(o.omega)
    ci, pj = np.nonzero(np.abs(lw[:, None] - lw[None, :]) <= window) if pairs is None else pairs
    pp = _params(X, att)
    Jv = j_of_points("lateral", rate_hz, pp, o.omega, o.ise, {k: v for k, v in pp.items() if k != "K"}, o.omega,
                     o.kp, o.kd, o.N, pairs=(ci, pj), scaling=GAIN_SCALING)
    J = np.full((P, P), J_MAX)
    J[ci, pj] = Jv
    np.fill_diagonal(J, 1.0)
    return J


def choose_rule(att: dict, X: np.ndarray, q_opt: np.ndarray, beta: float, rate_hz: float) -> dict[str, Any]:
    """``(pm, gain_scale)`` of the lateral rule at ``beta``: the candidate whose gains keep the most of
    the sample ``X`` stable at ``rate_hz``, then the least worst J against the optima ``q_opt``.

    Returns
    -------
    dict: ``pm_deg``, ``gain_scale``, ``stable_fraction``, ``worst_J`` (None if none stable), ``median_J``.
    """
    from uavsim.tuning.rule import rule_constants
    from uavsim.tuning.sensitivity import controller_ise

    pp = _params(X, att)
    g = TuningRule(beta, DEFAULT_PM_DEG).gains_batch("lateral", **pp)
    rows = []
    for pm in _PMS:
        for sc in _SCALES:
            try:
                c1, c3 = rule_constants(beta, pm, sc)
            except UserError:  # the derivative lead out of (0, 90) deg
                continue
            kp = c1 / g["gain_at_omega"]
            q = controller_ise("lateral", rate_hz, pp, kp, kp * c3 * 2 * np.pi / g["omega"], g["N"])
            ok = np.isfinite(q)
            Jr = q[ok] / q_opt[ok]
            rows.append((float(ok.mean()), -float(Jr.max()) if ok.any() else -math.inf, pm, sc,
                         float(np.median(Jr)) if ok.any() else None))
    frac, negw, pm, sc, med = max(rows)
    return {"pm_deg": pm, "gain_scale": sc, "stable_fraction": frac,
            "worst_J": -negw if math.isfinite(negw) else None, "median_J": med, "n_points": len(X)}


def design_subgrid(att: dict, rng: np.random.Generator, rate_hz: float = DEFAULT_RATE_HZ, *,
                   n_samples: int = N_SAMPLES, cover_J: float = COVER_J, neighbour_J: float = NEIGHBOUR_J,
                   window: float = OMEGA_WINDOW, tau_obs: float = TAU_OBS) -> Grid:
    """The lateral sub-grid of one attitude class (module docstring); ``att`` from ``attitude_of``
    with the attitude table (``rate_hz`` included)."""
    from uavsim.tuning.table import build_flat_table

    t0 = time.time()
    if float(att.get("rate_hz", math.nan)) != float(rate_hz):
        raise UserError(f"the attitude loop of a lateral sub-grid must be sampled at {rate_hz:g} Hz")
    X = _sample(rng, n_samples)
    bch = choose_beta(att, X, tau_obs)
    beta = bch["beta"]
    o = optimal_gains("lateral", rate_hz, rule=TuningRule(beta, DEFAULT_PM_DEG), **_params(X, att))
    has = np.isfinite(o.ise)
    if not has.all():  # a point no PD holds at the rate cannot be covered: say so, design on the rest
        X = X[has]
        o = optimal_gains("lateral", rate_hz, rule=TuningRule(beta, DEFAULT_PM_DEG), **_params(X, att))
    J = _pair_J(att, X, o, rate_hz, window)
    cls = cover(J, cover_J)
    # the classes on each other in full (the window leaves corners without any)
    ci, ck = (a.ravel() for a in np.meshgrid(cls, cls, indexing="ij"))
    far = J[ci, ck] >= J_MAX
    J[ci[far], ck[far]] = _pair_J(att, X, o, rate_hz, np.inf, pairs=(ci[far], ck[far]))[ci[far], ck[far]]
    nb = class_neighbours(J[cls], J[np.ix_(cls, cls)], neighbour_J)
    rch = choose_rule(att, X[:_N_RULE], o.ise[:_N_RULE], beta, rate_hz)
    rule = TuningRule(beta, rch["pm_deg"], rch["gain_scale"])
    Xc = np.vectorize(lambda v: float(f"{v:.8g}"))(X[cls])  # as the grid file stores them
    pc = _params(Xc, att)
    g = rule.gains_batch("lateral", **pc)
    period, amp, p_spread, a_spread = sampled_relay_cycle(beta, rate_hz, spread=True, **pc)
    if not np.all(np.isfinite(period)):
        raise UserError(f"lateral sub-grid of attitude class {att.get('att_class')}: no settled relay cycle for "
                        f"classes {np.flatnonzero(~np.isfinite(period)).tolist()}")
    c1, c3 = rule.constants
    best = J[cls].min(axis=0)
    built = {"beta_choice": bch, "rule_choice": rch, "n_sample": int(len(X) + (~has).sum()),
             "n_without_optimum": int((~has).sum()), "cover_J": cover_J, "neighbour_J": neighbour_J,
             "omega_window": window, "n_pairs_evaluated": int(np.count_nonzero(J < J_MAX)),
             "sample_best_J": {"median": float(np.median(best)), "max": float(best.max())},
             "cycle_over_df": [float(v) for v in np.quantile(period * g["omega"] / (2 * np.pi), [0.0, 0.5, 1.0])],
             # per class: how much the last 8 cycles differ in length and in amplitude ((max - min) / mean)
             "cycle_period_spread": [round(float(v), 4) for v in p_spread],
             "cycle_amplitude_spread": [round(float(v), 4) for v in a_spread]}
    sub = Grid(loop="lateral", version=GRID_VERSION, params={"T2": Xc[:, 0], "tau": Xc[:, 1]}, kp=g["kp"], kd=g["kd"],
               derivative_filter_hz=g["derivative_filter_hz"], omega=2 * np.pi / period, amplitude=amp,
               omega_df=g["omega"], J=np.ones((len(cls), len(cls))), beta=beta, pm_deg=rule.pm_deg, c1=c1, c3=c3,
               built=built, gain_scale=rule.gain_scale, attitude=att, neighbours=[[int(i), int(k)] for i, k in nb])
    # the sub-grid's J: the table's, of its robust answers
    t = build_flat_table("lateral", rate_hz, sub, {k: v for k, v in pc.items() if k != "K"}, {}, att, scaling=GAIN_SCALING)
    sub.J = t.J_robust
    built["build_time_s"] = round(time.time() - t0, 1)
    return sub


def build_lateral(seed: int = 0, rate_hz: float = DEFAULT_RATE_HZ, log=None, att_classes=None, **kw) -> Grid:
    """The lateral grid: ``design_subgrid`` over every attitude class with its table PD at ``rate_hz``.

    ``att_classes`` (default all) restricts the build (a partial grid, for experiments); ``kw`` goes
    to ``design_subgrid``. Returns an unsaved ``Grid`` with one sub-grid per attitude class.
    """
    import datetime as _dt

    from uavsim import __version__ as tool_version
    from uavsim.tuning.table import load_table

    t0 = time.time()
    att_grid = load_grid("attitude")
    att_table = load_table("attitude", rate_hz, grid=att_grid)
    rng = np.random.default_rng(seed)
    subs = []
    todo = range(att_grid.n) if att_classes is None else att_classes
    for a in todo:
        subs.append(design_subgrid(attitude_of(att_grid, a, att_table), rng, rate_hz, **kw))
        if log:
            s = subs[-1]
            log(f"lateral sub-grid {a + 1}/{att_grid.n}: beta {s.beta:g} (T0 {s.built['beta_choice']['T0_min']:.2f} s), "
                f"{s.n} classes, {len(s.neighbours)} neighbour pairs, rule pm {s.pm_deg:g} scale {s.gain_scale:g} "
                f"({time.time() - t0:.0f} s)")
    rule = TuningRule()
    c1, c3 = rule.constants
    built = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "tool_version": tool_version,
             "seed": seed, "rate_hz": float(rate_hz), "attitude_hash": att_grid.hash, "attitude_pd_hash": att_table.pd_hash,
             "tau_obs": kw.get("tau_obs", TAU_OBS), "cover_J": kw.get("cover_J", COVER_J),
             "neighbour_J": kw.get("neighbour_J", NEIGHBOUR_J), "n_samples": kw.get("n_samples", N_SAMPLES),
             "method": "per attitude class over its attitude table PD sampled at the rate: beta the lowest NP-MRFT "
                       "allows tau_obs on the fastest cycle; classes a greedy cover of a box sample by the table's "
                       f"J (optima, {GAIN_SCALING} gain estimate); neighbours the two best classes per sample point; J the "
                       "robust answers'",
             "lateral_rules": [[s.beta, s.pm_deg, s.gain_scale] for s in subs]}
    g = Grid(loop="lateral", version=GRID_VERSION, params={}, kp=np.zeros(0), kd=np.zeros(0),
             derivative_filter_hz=np.zeros(0), omega=np.zeros(0), amplitude=np.zeros(0), omega_df=np.zeros(0),
             J=np.zeros((0, 0)), beta=rule.beta, pm_deg=rule.pm_deg, c1=c1, c3=c3, built=built, sub=subs)
    built["build_time_s"] = round(time.time() - t0, 1)
    return g
